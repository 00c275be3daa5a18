"""`btf-host resolve`: facet-based or statistical modelling at a sensor resolution."""
from __future__ import annotations

import argparse
import json

from tools.cli import CliError
from tools.resolve import MIN_GRAINS_PER_PIXEL, bounds


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("resolve", help="facet-based or statistical modelling for a grain size",
                       description="Bounds relating wavelength, grain size and pixel footprint (Section 2).")
    p.add_argument("--grain-mm", type=float, required=True, help="grain size D in mm")
    p.add_argument("--wavelength-nm", type=float, required=True, help="wavelength in nm")
    p.add_argument("--pixel-mm", type=float, help="pixel footprint on the surface in mm")
    p.add_argument("--incidence-deg", type=float, default=0.0, help="angle of incidence (default 0)")
    p.add_argument("--na", type=float, default=1.0, help="numerical aperture of the optics (default 1)")
    p.add_argument("--json", action="store_true")
    return p


def run(args: argparse.Namespace) -> int:
    try:
        b = bounds(args.grain_mm, args.wavelength_nm, args.pixel_mm, args.incidence_deg, args.na)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.json:
        print(json.dumps(b.to_json(), indent=1))
        return 0
    print(f"diffraction limit  lambda/(2 NA)           {b.diffraction_limit_nm:10.2f} nm")
    print(f"Rayleigh smooth    lambda/(8 cos theta)    {b.rayleigh_height_nm:10.2f} nm")
    print(f"Fraunhofer smooth  lambda/(32 cos theta)   {b.fraunhofer_height_nm:10.2f} nm")
    print(f"widest flat facet  2 sqrt(D h - h^2)       {b.max_flat_facet_nm:10.2f} nm "
          f"({b.facets_across_grain:.1f} across a grain)")
    print(f"facet pixels       P <= D/2                {b.nyquist_pixel_mm:10.4f} mm")
    print(f"statistical pixels P >= D sqrt({MIN_GRAINS_PER_PIXEL})          {b.statistical_pixel_mm:10.4f} mm")
    if b.verdict is not None:
        print(f"pixel {b.pixel_mm:g} mm covers {b.grains_per_pixel:.1f} grains: {b.verdict.value}")
    return 0
