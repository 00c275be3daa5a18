"""Facet-based or statistical modelling? The resolution rule of the paper's Section 2.

A surface can be rendered from facets only if the sensor resolves its grains and the
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
