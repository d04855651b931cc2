#!/usr/bin/env python3
"""Generates the committed air-kerma reference used by `sim_core::fluoro::dose`.

Pinned version (the script refuses to run with another, so the committed CSVs stay reproducible):
    spekpy==2.5.4   (physics model "spekpy-v2-casim")

Exact command (from the repository root):
    pip install spekpy==2.5.4
    python3 sim-core/data/fluoro/generate_kerma.py sim-core/data/fluoro

Spectrum settings are those of `generate_spectra.py`: tungsten target, 10 degree anode angle,
1 keV bins, 6.3 mm Al, 40 to 120 kVp every 5 kVp. Writes
- `air_kerma_spekpy.csv`: SpekPy's own `get_kerma()` per kVp, uGy per mAs at 100 cm (the
  reference the Rust sum is tested against);
- `muen_air_cm2_per_g.csv`: SpekPy's mass energy-absorption coefficient of air,
  `muen_air_data.get_muen_over_rho_air(k)`, on the same bin centres 1.5 .. 119.5 keV (the table
  the Rust sum uses; SpekPy's `get_kerma()` uses the same table on the same grid).
"""

import sys
from importlib.metadata import version

import numpy as np
import spekpy

EXPECTED = {"spekpy": "2.5.4"}
KVPS = list(range(40, 121, 5))
CENTRES_KEV = np.arange(1, 120) + 0.5


def spek(kvp):
    s = spekpy.Spek(kvp=kvp, th=10, dk=1, targ="W", physics="spekpy-v2-casim")
    s.filter("Al", 6.3)
    return s


def main(out_dir):
    versions = {"spekpy": version("spekpy")}
    if versions != EXPECTED:
        sys.exit(f"need {EXPECTED}, found {versions}")

    with open(f"{out_dir}/air_kerma_spekpy.csv", "w") as fh:
        fh.write("kvp,air_kerma_ugy_per_mas_at_100cm\n")
        for kvp in KVPS:
            s = spek(kvp)
            kerma = s.get_kerma()
            fh.write(f"{kvp},{kerma:.6e}\n")
            print(f"{kvp} kVp: {kerma:.4f} uGy/mAs at 100 cm")

    # The highest voltage's model covers every bin centre up to 119.5 keV.
    s = spek(120)
    k, _ = s.get_spectrum()
    assert np.allclose(k, CENTRES_KEV), (k[:3], k[-3:])
    muen = s.muen_air_data.get_muen_over_rho_air(k)
    with open(f"{out_dir}/muen_air_cm2_per_g.csv", "w") as fh:
        fh.write("energy_kev,muen_over_rho_air_cm2_per_g\n")
        for e, m in zip(k, muen):
            fh.write(f"{e:.1f},{m:.6e}\n")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
