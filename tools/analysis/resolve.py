"""Facet-based or statistical modelling? The resolution rule of the paper's Section 2.

Two views. The **paper view** reproduces the paper's own derivation: the geometric-optics
condition lambda << facet << dA, read with three factors as

    Kpf Kfl Kr lambda^2 < Kpf (facet area) < dA

(Kpf pixel area per facet area, Kfl facet area per lambda^2, Kr rays per facet; the paper
takes 1000, 1000 and 100), with dA one grain's viewing area D^2 and facets and grains
taken as spheres (area 4 pi r^2). It gives four bounds: the widest facet and the longest
wavelength dA allows, the smallest grain the wavelength allows and the longest wavelength
the grain allows. For sand (D = 0.02 mm, lambda = 700 nm) they are 356.82 nm, 2 nm,
0.125 mm and 112.1 nm, and every one rules facets out.

The **physical view** asks what optics and surface roughness allow. A surface can be rendered from facets only if the sensor resolves its grains and the
grains are large, smooth reflectors at the wavelength; when one pixel integrates many
grains, only the statistics of the grain population survive, and a per-pixel
statistical model (our Johnson BTF) is the right one. The bounds, all for wavelength L,
grain size D and pixel footprint P on the surface:

- diffraction limit  d_min = L / (2 NA)         (Abbe; NA = 1 is the best any optics does)
  the smallest detail any sensor can resolve;
- Rayleigh smoothness h_R = L / (8 cos theta)    a facet is a specular reflector when its
  height deviations stay below this; Fraunhofer's stricter form is L / (32 cos theta);
- facet sagitta      s = D / 2 - sqrt((D / 2)^2 - (w / 2)^2) for a facet of width w on a
  spherical grain; the widest flat facet (s <= h_R) is w_max = 2 sqrt(D h_R - h_R^2);
- Nyquist            P <= D / 2 to resolve a grain with two pixels;
- statistical        P >= D sqrt(N_min): a pixel integrates at least N_min grains.
"""
from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass

# A pixel integrating at least this many grains sees only their statistics.
MIN_GRAINS_PER_PIXEL = 25


# The paper's worked example (Section 2): the smallest sand grain at the longest visible wavelength.
PAPER_GRAIN_MM = 0.02
PAPER_WAVELENGTH_NM = 700.0
PAPER_PIXEL_PER_FACET = 1000.0
PAPER_FACET_PER_WAVELENGTH2 = 1000.0
PAPER_RAYS_PER_FACET = 100.0


class Verdict(enum.StrEnum):
    FACET = "facet"
    STATISTICAL = "statistical"
    MIXED = "mixed"
    UNRESOLVABLE = "unresolvable"


@dataclass(frozen=True, slots=True)
class Bounds:
    grain_mm: float
    wavelength_nm: float
    incidence_deg: float
    numerical_aperture: float
    diffraction_limit_nm: float
    rayleigh_height_nm: float
    fraunhofer_height_nm: float
    max_flat_facet_nm: float
    facets_across_grain: float
    nyquist_pixel_mm: float
    statistical_pixel_mm: float
    pixel_mm: float | None
    grains_per_pixel: float | None
    verdict: Verdict | None

    def to_json(self) -> dict:
        d = asdict(self)
        d["verdict"] = None if self.verdict is None else self.verdict.value
        return d


def bounds(grain_mm: float, wavelength_nm: float, pixel_mm: float | None = None,
           incidence_deg: float = 0.0, numerical_aperture: float = 1.0) -> Bounds:
    for name, v in (("grain size", grain_mm), ("wavelength", wavelength_nm)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v}")
    if pixel_mm is not None and not (math.isfinite(pixel_mm) and pixel_mm > 0):
        raise ValueError(f"pixel footprint must be a positive number, got {pixel_mm}")
    if not 0.0 <= incidence_deg < 90.0:
        raise ValueError(f"incidence angle must lie in [0, 90) degrees, got {incidence_deg}")
    if not 0.0 < numerical_aperture <= 1.0:
        raise ValueError(f"numerical aperture must lie in (0, 1], got {numerical_aperture}")
    d_nm = grain_mm * 1e6
    cos_t = math.cos(math.radians(incidence_deg))
    h_r = wavelength_nm / (8.0 * cos_t)
    h_f = wavelength_nm / (32.0 * cos_t)
    d_min = wavelength_nm / (2.0 * numerical_aperture)
    # Widest chord of a sphere of diameter D whose sagitta stays below h_R.
    # sqrt(h) sqrt(D - h) rather than sqrt(D h - h^2): no overflow for extreme sizes.
    w = 2.0 * math.sqrt(h_r) * math.sqrt(d_nm - h_r) if h_r < d_nm / 2 else d_nm
    nyquist = grain_mm / 2.0
    stat = grain_mm * math.sqrt(MIN_GRAINS_PER_PIXEL)
    verdict = grains = None
    if pixel_mm is not None:
        grains = (pixel_mm / grain_mm) * (pixel_mm / grain_mm)
        if d_nm < d_min or w < d_min:
            # Grains or their facets lie below the diffraction limit: no sensor sees facets.
            verdict = Verdict.STATISTICAL if pixel_mm >= stat else Verdict.UNRESOLVABLE
        elif pixel_mm <= nyquist:
            verdict = Verdict.FACET
        elif pixel_mm >= stat:
            verdict = Verdict.STATISTICAL
        else:
            verdict = Verdict.MIXED
    b = Bounds(grain_mm, wavelength_nm, incidence_deg, numerical_aperture, d_min, h_r, h_f,
               w, d_nm / w, nyquist, stat, pixel_mm, grains, verdict)
    if not all(math.isfinite(v) and (v > 0 or k == "incidence_deg") for k, v in asdict(b).items()
               if isinstance(v, float)):
        raise ValueError("grain size, wavelength and pixel footprint are too far apart for "
                         "floating point; give them in sensible units")
    return b


@dataclass(frozen=True, slots=True)
class PaperBound:
    """One bound of the paper's derivation: `value` is an upper or lower `limit` on the
    quantity whose actual size is `actual` (None for the facet, which has no given size;
    `actual` is then the smallest facet the wavelength allows)."""
    name: str
    quantity: str
    formula: str
    inputs: dict[str, float]
    value: float
    unit: str
    limit: str  # "upper" or "lower"
    actual: float
    rules_out_facets: bool


@dataclass(frozen=True, slots=True)
class PaperView:
    grain_mm: float
    wavelength_nm: float
    pixel_per_facet: float
    facet_per_wavelength2: float
    rays_per_facet: float
    pixel_area_nm2: float
    bounds: tuple[PaperBound, ...]
    verdict: Verdict

    def to_json(self) -> dict:
        d = asdict(self)
        d["verdict"] = self.verdict.value
        return d


def paper_bounds(grain_mm: float = PAPER_GRAIN_MM, wavelength_nm: float = PAPER_WAVELENGTH_NM,
                 pixel_per_facet: float = PAPER_PIXEL_PER_FACET,
                 facet_per_wavelength2: float = PAPER_FACET_PER_WAVELENGTH2,
                 rays_per_facet: float = PAPER_RAYS_PER_FACET) -> PaperView:
    """The paper's four bounds for grain size D, wavelength lambda and the three factors."""
    named = {"grain size": grain_mm, "wavelength": wavelength_nm, "pixel per facet": pixel_per_facet,
             "facet per wavelength^2": facet_per_wavelength2, "rays per facet": rays_per_facet}
    for name, v in named.items():
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v}")
    kpf, kfl, kr, lam = pixel_per_facet, facet_per_wavelength2, rays_per_facet, wavelength_nm
    d_nm = grain_mm * 1e6
    da = d_nm * d_nm  # one grain's viewing area
    chain = kpf * kfl * kr  # the whole factor chain on lambda^2
    four_pi = 4.0 * math.pi
    # (1) facet area < dA / Kpf, as a sphere's 4 pi (d/2)^2; the wavelength wants Kfl Kr lambda^2.
    facet_max = 2.0 * math.sqrt(da / (four_pi * kpf))
    facet_min = 2.0 * math.sqrt(kfl * kr / four_pi) * lam
    lam_pixel = math.sqrt(da / chain)
    # (2) the wavelength bounds the grain: Kpf Kfl Kr lambda^2 < Kpf 4 pi (D/2)^2.
    grain_min = 2.0 * math.sqrt(chain / (kpf * four_pi)) * lam
    # (3) the grain bounds the wavelength, the same inequality solved for lambda.
    lam_grain = math.sqrt(kpf * four_pi / chain) * (d_nm / 2.0)
    factors = {"pixel_per_facet": kpf, "facet_per_wavelength2": kfl, "rays_per_facet": kr}
    bounds_ = (
        PaperBound("facet_diameter", "facet diameter", "d < 2 sqrt(dA / (4 pi Kpf)), dA = D^2",
                   {"grain_mm": grain_mm, "pixel_per_facet": kpf}, facet_max, "nm", "upper",
                   facet_min, facet_min >= facet_max),
        PaperBound("wavelength_from_pixel", "wavelength", "lambda < sqrt(dA / (Kpf Kfl Kr)), dA = D^2",
                   {"grain_mm": grain_mm, **factors}, lam_pixel, "nm", "upper", lam, lam >= lam_pixel),
        PaperBound("grain_size", "grain diameter",
                   "D > 2 sqrt(Kpf Kfl Kr lambda^2 / (4 pi Kpf))",
                   {"wavelength_nm": lam, **factors}, grain_min, "nm", "lower", d_nm, d_nm <= grain_min),
        PaperBound("wavelength_from_grain", "wavelength",
                   "lambda < sqrt(Kpf 4 pi (D/2)^2 / (Kpf Kfl Kr))",
                   {"grain_mm": grain_mm, **factors}, lam_grain, "nm", "upper", lam, lam >= lam_grain),
    )
    if not all(math.isfinite(v) and v > 0 for b in bounds_ for v in (b.value, b.actual)) \
            or not math.isfinite(da) or da <= 0:
        raise ValueError("grain size, wavelength and factors are too far apart for floating point; "
                         "give them in sensible units")
    verdict = Verdict.STATISTICAL if any(b.rules_out_facets for b in bounds_) else Verdict.FACET
    return PaperView(grain_mm, lam, kpf, kfl, kr, da, bounds_, verdict)
