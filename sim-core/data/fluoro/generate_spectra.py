#!/usr/bin/env python3
"""Generates the committed X-ray spectra and mass-attenuation tables used by `sim_core::fluoro`.

Pinned versions (the script refuses to run with others, so the committed CSVs stay reproducible):
    spekpy==2.5.4   (tube spectra; physics model "spekpy-v2-casim")
    xraydb==4.5.8   (mass attenuation coefficients, `mu_elam`, total cross-section incl. coherent)

Exact command (from the repository root):
    pip install spekpy==2.5.4 xraydb==4.5.8
    python3 sim-core/data/fluoro/generate_spectra.py sim-core/data/fluoro

Bin convention: 1 keV bins [n, n+1) keV; every table row is the bin centre n + 0.5 keV, which is
what SpekPy's `get_spectrum()` returns with `dk=1` (its first bin is 1.5 keV). The attenuation
tables are evaluated at the same bin centres. Rows run from 1.5 to 119.5 keV; a spectrum's bins
above its kVp are zero.
"""

import sys
from importlib.metadata import version

import numpy as np
import spekpy
import xraydb

EXPECTED = {"spekpy": "2.5.4", "xraydb": "4.5.8"}
KVPS = list(range(40, 121, 5))
CENTRES_KEV = np.arange(1, 120) + 0.5

# NIST "Bone, Compact (ICRU)" mass fractions (NIST X-ray mass attenuation coefficient tables,
# Table 2, composition of materials; density 1.85 g/cm^3). xraydb has no bone material of its own.
BONE_COMPACT_ICRU = {
    "H": 0.063984,
    "C": 0.278000,
    "N": 0.027000,
    "O": 0.410016,
    "Mg": 0.002000,
    "P": 0.070000,
    "S": 0.002000,
    "Ca": 0.147000,
}
# Water by mass fraction (H2O with xraydb's atomic masses).
WATER = {
    "H": 2 * xraydb.atomic_mass("H") / (2 * xraydb.atomic_mass("H") + xraydb.atomic_mass("O")),
    "O": xraydb.atomic_mass("O") / (2 * xraydb.atomic_mass("H") + xraydb.atomic_mass("O")),
}


def mass_atten(fractions, energies_ev):
    """Total mass attenuation coefficient (cm^2/g) of a mixture by mass fractions."""
    total = sum(fractions.values())
    assert abs(total - 1.0) < 1e-6, total
    return sum(w * xraydb.mu_elam(el, energies_ev, kind="total") for el, w in fractions.items())


def main(out_dir):
    versions = {"spekpy": version("spekpy"), "xraydb": xraydb.__version__}
    if versions != EXPECTED:
        sys.exit(f"need {EXPECTED}, found {versions}")

    # Spectra: tungsten target, 10 degree anode angle, 6.3 mm Al, 1 keV bins (fluence per keV,
    # SpekPy's default units: photons keV^-1 cm^-2 mAs^-1 at 100 cm; only relative values matter).
    rows = {}
    for kvp in KVPS:
        s = spekpy.Spek(kvp=kvp, th=10, dk=1, targ="W", physics="spekpy-v2-casim")
        s.filter("Al", 6.3)
        k, f = s.get_spectrum()
        assert np.allclose(k, np.arange(1, kvp) + 0.5), (kvp, k[:3], k[-3:])
        col = np.zeros(len(CENTRES_KEV))
        # SpekPy reports the lowest bins as 1e-265-like denormal noise; they are zero for any use.
        col[: len(f)] = np.where(f < 1e-20, 0.0, f)
        rows[kvp] = col
        if kvp == 80:
            print(f"80 kVp mean energy {s.get_emean():.3f} keV")
    with open(f"{out_dir}/spectra_w10_al6p3.csv", "w") as fh:
        fh.write("energy_kev," + ",".join(f"kvp{k}" for k in KVPS) + "\n")
        for i, e in enumerate(CENTRES_KEV):
            fh.write(f"{e:.1f}," + ",".join(f"{rows[k][i]:.6e}" for k in KVPS) + "\n")

    ev = CENTRES_KEV * 1000.0
    tables = {
        "water": mass_atten(WATER, ev),
        "bone_compact_icru": mass_atten(BONE_COMPACT_ICRU, ev),
        "iodine": xraydb.mu_elam("I", ev, kind="total"),
        "aluminium": xraydb.mu_elam("Al", ev, kind="total"),
        "iron": xraydb.mu_elam("Fe", ev, kind="total"),
    }
    names = list(tables)
    with open(f"{out_dir}/mass_attenuation_cm2_per_g.csv", "w") as fh:
        fh.write("energy_kev," + ",".join(names) + "\n")
        for i, e in enumerate(CENTRES_KEV):
            fh.write(f"{e:.1f}," + ",".join(f"{tables[n][i]:.6e}" for n in names) + "\n")
    # The single-energy mode and the 60 keV scaling need the coefficient at exactly 60 keV, which
    # is not a bin centre.
    fractions = {"water": WATER, "bone_compact_icru": BONE_COMPACT_ICRU, "iodine": {"I": 1.0},
                 "aluminium": {"Al": 1.0}, "iron": {"Fe": 1.0}}
    with open(f"{out_dir}/mass_attenuation_60kev.csv", "w") as fh:
        fh.write("material,mu_over_rho_cm2_per_g\n")
        for n in names:
            at60 = float(mass_atten(fractions[n], np.array([60000.0]))[0])
            fh.write(f"{n},{at60:.6e}\n")
            print(f"{n}: mu/rho(60 keV) = {at60:.4f} cm^2/g")

if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
