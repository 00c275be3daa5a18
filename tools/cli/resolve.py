"""`btf-host resolve`: facet-based or statistical modelling, in the paper's view and the physical one."""
from __future__ import annotations

import argparse
import json

from tools.analysis.resolve import (
    MIN_GRAINS_PER_PIXEL,
    PAPER_FACET_PER_WAVELENGTH2,
    PAPER_GRAIN_MM,
    PAPER_PIXEL_PER_FACET,
    PAPER_RAYS_PER_FACET,
    PAPER_WAVELENGTH_NM,
    Bounds,
    PaperView,
    bounds,
    paper_bounds,
)
from tools.cli.options import CliError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("Bounds relating wavelength, grain size and pixel footprint: the paper's Section 2 derivation "
                     "(its worked example, sand, by default) and the physical view (diffraction and smoothness).")
    p.add_argument("--grain-mm", type=float, default=PAPER_GRAIN_MM,
                   help=f"grain diameter D in mm (default {PAPER_GRAIN_MM:g}, the paper's smallest sand grain)")
    p.add_argument("--wavelength-nm", type=float, default=PAPER_WAVELENGTH_NM,
                   help=f"wavelength in nm (default {PAPER_WAVELENGTH_NM:g}, the longest visible)")
    p.add_argument("--pixel-per-facet", type=float, default=PAPER_PIXEL_PER_FACET,
                   help=f"paper view: pixel area over facet area (default {PAPER_PIXEL_PER_FACET:g})")
    p.add_argument("--facet-per-wavelength2", type=float, default=PAPER_FACET_PER_WAVELENGTH2,
                   help=f"paper view: facet area over wavelength squared (default {PAPER_FACET_PER_WAVELENGTH2:g})")
    p.add_argument("--rays-per-facet", type=float, default=PAPER_RAYS_PER_FACET,
                   help=f"paper view: rays per facet (default {PAPER_RAYS_PER_FACET:g})")
    p.add_argument("--pixel-mm", type=float, help="physical view: pixel footprint on the surface in mm")
    p.add_argument("--incidence-deg", type=float, default=0.0, help="physical view: angle of incidence (default 0)")
    p.add_argument("--na", type=float, default=1.0, help="physical view: numerical aperture (default 1)")
    p.add_argument("--json", action="store_true", help="print both views as one JSON document")


SYMBOLS = {"grain_mm": ("D", " mm"), "wavelength_nm": ("lambda", " nm"), "pixel_per_facet": ("Kpf", ""),
           "facet_per_wavelength2": ("Kfl", ""), "rays_per_facet": ("Kr", "")}


def _fixed(v: float) -> str:
    """A length in a 10-wide column: fixed point where that reads, else in powers of ten."""
    return f"{v:10.2f}" if 1e-2 <= abs(v) < 1e9 else f"{v:10.3g}"


def _number(v: float, unit: str, grain: bool = False) -> str:
    if unit == "nm" and (grain or v >= 1e5):  # grains: nm as the paper writes them, and mm
        return f"{v:.3f} nm = {v / 1e6:.3f} mm"
    return f"{v:.2f} {unit}" if 1e-2 <= v < 1e9 else f"{v:.4g} {unit}"


def paper_lines(p: PaperView) -> list[str]:
    lines = ["paper view (Section 2): lambda << facet << dA, read as "
             "Kpf Kfl Kr lambda^2 < Kpf facet area < dA",
             f"  inputs: D {p.grain_mm:g} mm, lambda {p.wavelength_nm:g} nm, Kpf (pixel/facet) "
             f"{p.pixel_per_facet:g}, Kfl (facet/lambda^2) {p.facet_per_wavelength2:g}, "
             f"Kr (rays per facet) {p.rays_per_facet:g}; dA = D^2 = {p.pixel_area_nm2:.4g} nm^2"]
    for k, b in enumerate(p.bounds, start=1):
        sign = "<" if b.limit == "upper" else ">"
        grain = b.name == "grain_size"
        given = ("the wavelength needs facets of at least " + _number(b.actual, b.unit)
                 if b.name == "facet_diameter" else f"actual {_number(b.actual, b.unit, grain)}")
        lines.append(f"  ({k}) {b.quantity} {sign} {_number(b.value, b.unit, grain)}   "
                     f"[{'rules out facets' if b.rules_out_facets else 'allows facets'}: {given}]")
        inputs = ", ".join(f"{SYMBOLS[n][0]} {v:g}{SYMBOLS[n][1]}" for n, v in b.inputs.items())
        lines.append(f"      {b.formula}; {inputs}")
    ruled = sum(b.rules_out_facets for b in p.bounds)
    lines.append(f"  verdict (paper view): {p.verdict.value} ({ruled} of {len(p.bounds)} bounds rule out facets)")
    return lines


def physical_lines(b: Bounds) -> list[str]:
    lines = ["physical view: diffraction and smoothness",
             f"  diffraction limit  lambda/(2 NA)           {_fixed(b.diffraction_limit_nm)} nm",
             f"  Rayleigh smooth    lambda/(8 cos theta)    {_fixed(b.rayleigh_height_nm)} nm",
             f"  Fraunhofer smooth  lambda/(32 cos theta)   {_fixed(b.fraunhofer_height_nm)} nm",
             f"  widest flat facet  2 sqrt(D h - h^2)       {_fixed(b.max_flat_facet_nm)} nm "
             f"({b.facets_across_grain:.1f} across a grain)",
             f"  facet pixels       P <= D/2                {b.nyquist_pixel_mm:10.4f} mm",
             f"  statistical pixels P >= D sqrt({MIN_GRAINS_PER_PIXEL})          {b.statistical_pixel_mm:10.4f} mm"]
    if b.verdict is None:
        lines.append("  verdict (physical view): give --pixel-mm, the pixel footprint on the surface")
    else:
        lines.append(f"  verdict (physical view): {b.verdict.value} (pixel {b.pixel_mm:g} mm covers "
                     f"{b.grains_per_pixel:.3g} grains)")
    return lines


def run(args: argparse.Namespace) -> int:
    try:
        paper = paper_bounds(args.grain_mm, args.wavelength_nm, args.pixel_per_facet,
                             args.facet_per_wavelength2, args.rays_per_facet)
        physical = bounds(args.grain_mm, args.wavelength_nm, args.pixel_mm, args.incidence_deg, args.na)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.json:
        print(json.dumps({"paper": paper.to_json(), "physical": physical.to_json()}, indent=1))
        return 0
    print("\n".join(paper_lines(paper) + [""] + physical_lines(physical)))
    return 0
