"""Analytic channel solutions (Morris et al. 1997; thesis eqs. 4.4 and 4.5 with the sign slips
of 4.5 corrected), for checking snapshots independently of the Fortran code."""
import numpy as np


def couette(y, t, wall_speed, width, nu, terms=2000):
    """Plate at y = width moving at wall_speed from t = 0; t = inf gives the steady profile."""
    y = np.asarray(y, dtype=float)
    v = wall_speed * y / width
    if np.isinf(t):
        return v
    if t <= 0:
        return np.zeros_like(y)
    for n in range(1, terms + 1):
        decay = np.exp(-nu * (n * np.pi / width) ** 2 * t)
        v = v + 2 * wall_speed / (n * np.pi) * (-1) ** n * np.sin(n * np.pi * y / width) * decay
        if decay < 1e-18:
            break
    return v


def poiseuille(y, t, force, width, nu, terms=2000):
    """Body force per unit mass `force` along x from t = 0 between resting plates."""
    y = np.asarray(y, dtype=float)
    v = force / (2 * nu) * y * (width - y)
    if np.isinf(t):
        return v
    if t <= 0:
        return np.zeros_like(y)
    for n in range(terms):
        k = 2 * n + 1
        decay = np.exp(-(k * np.pi / width) ** 2 * nu * t)
        v = v - 4 * force * width ** 2 / (nu * np.pi ** 3 * k ** 3) * np.sin(k * np.pi * y / width) * decay
        if decay < 1e-18:
            break
    return v


def channel(case, y, t, par):
    """The velocity along the flow of the channel par (sph_error_table.channel_parameters) at
    distances y from its resting wall, time t (inf: steady), as the program's reference
    (sph_reference): 'poiseuille' the body force's series; 'couette' the moving wall's plus,
    where there is one, the body force's (the problem is linear; the Poiseuille profile is
    the same from either wall). None for another case."""
    if case == "poiseuille":
        return poiseuille(y, t, par["force"], par["width"], par["nu"])
    if case == "couette":
        v = couette(y, t, par["wall_speed"], par["width"], par["nu"])
        if par["force"] != 0.0:
            v = v + poiseuille(y, t, par["force"], par["width"], par["nu"])
        return v
    return None


if __name__ == "__main__":
    import sys
    # (a library of the other scripts: run on its own it did nothing, and said nothing)
    sys.exit("sph_analytic.py is a module of the post-processing scripts (import "
             "sph_analytic; couette(y, t, U, L, nu), poiseuille(y, t, F, L, nu)); to compare "
             "snapshots with these profiles use scripts/sph_error_table.py")
