#!/usr/bin/env python3
"""Generates the interaction tables of the scatter Monte Carlo reference (`sim_core::fluoro::scatter`).

Pinned version (the script refuses to run with another, so the committed CSVs stay reproducible):
    xraydb==4.5.8   (Elam, Ravel and Sieber cross sections; Waasmaier-Kirfel form factors)

Exact command (from the repository root):
    pip install xraydb==4.5.8
    python3 sim-core/data/fluoro/generate_scatter.py sim-core/data/fluoro

Outputs:
    scatter_cross_sections.csv  water's photoabsorption, incoherent (Compton) and coherent
        (Rayleigh) mass attenuation coefficients and lead's total one, cm^2/g, at the 1 keV bin
        centres of the spectra (1.5 to 119.5 keV).
    water_form_factor.csv  the squared coherent form factor of a water molecule in the
        independent-atom approximation, F^2(x) = f_O(x)^2 + 2 f_H(x)^2, on
        x = sin(theta/2) / lambda from 0 to 3 per angstrom (0.01 steps), theta the scattering
        angle.
"""

import sys

import numpy as np
import xraydb

EXPECTED = "4.5.8"
CENTRES_KEV = np.arange(1, 120) + 0.5
WATER = {
    "H": 2 * xraydb.atomic_mass("H") / (2 * xraydb.atomic_mass("H") + xraydb.atomic_mass("O")),
    "O": xraydb.atomic_mass("O") / (2 * xraydb.atomic_mass("H") + xraydb.atomic_mass("O")),
}


def water(kind, energies_ev):
    return sum(w * xraydb.mu_elam(el, energies_ev, kind=kind) for el, w in WATER.items())


def main(out_dir):
    if xraydb.__version__ != EXPECTED:
        sys.exit(f"need xraydb {EXPECTED}, found {xraydb.__version__}")
    ev = CENTRES_KEV * 1000.0
    photo, incoh, coh = water("photo", ev), water("incoh", ev), water("coh", ev)
    total = water("total", ev)
    assert np.allclose(photo + incoh + coh, total, rtol=1e-9), "partial sums differ from total"
    lead = xraydb.mu_elam("Pb", ev, kind="total")
    with open(f"{out_dir}/scatter_cross_sections.csv", "w") as f:
        f.write("energy_kev,water_photo,water_incoherent,water_coherent,lead_total\n")
        for row in zip(CENTRES_KEV, photo, incoh, coh, lead):
            f.write(",".join(f"{v:.6e}" if i else f"{v:.1f}" for i, v in enumerate(row)) + "\n")
    x = np.round(np.arange(0, 301) * 0.01, 2)
    f2 = xraydb.f0("O", x) ** 2 + 2 * xraydb.f0("H", x) ** 2
    with open(f"{out_dir}/water_form_factor.csv", "w") as f:
        f.write("x_per_angstrom,f_squared\n")
        for xi, fi in zip(x, f2):
            f.write(f"{xi:.2f},{fi:.6e}\n")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
