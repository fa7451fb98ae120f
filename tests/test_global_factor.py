"""strain_limit.global_factor 'qdldl': the global strain step's systems factorised by QDLDL's
LDL^T (behaviors/materials/sparse_ldl.py) instead of SuperLU. The factor solves what SuperLU
solves (one right-hand side and several, as the Schur update and chord passes use it), and the
drape held by the step at a 1 % limit holds with it."""

import numpy as np
import scipy.sparse as sp

from lokigraph.behaviors.materials.sparse_ldl import LDLFactor
from lokigraph.behaviors.materials.strain_limit_global import GlobalStrainStep

from test_strain_limit_global import _drape, _ex


def test_ldl_solves_as_superlu_does():
    rng = np.random.default_rng(5)
    n = 400
    J = sp.random(n, 3 * n, density=0.004, random_state=rng, format="csr")
    R = (J @ J.T + sp.diags(1e-4 + 0.01 * rng.random(n))).tocsc()
    b = rng.standard_normal(n)
    B = rng.standard_normal((n, 3))
    g = GlobalStrainStep(4, np.array([[0, 1]], np.int64), np.ones(1), np.arange(1))
    g.fast = True
    x0 = g._splu(R).solve(b)
    f = LDLFactor(R)
    x1 = f.solve(b)
    X = f.solve(B)
    scale = np.abs(x0).max()
    assert np.abs(R @ x1 - b).max() < 1e-9 * np.abs(b).max()
    assert np.abs(x1 - x0).max() < 1e-8 * scale
    assert X.shape == B.shape and np.abs(R @ X - B).max() < 1e-9 * np.abs(B).max()
    # a principal submatrix, as the pivots factorise them
    g._principal_of(R.tocsr())
    idx = np.flatnonzero(rng.random(n) < 0.6)
    g.ldl = True
    y = g._factorise(R.tocsr(), idx).solve(b[idx])
    assert np.abs(R[idx][:, idx] @ y - b[idx]).max() < 1e-9 * np.abs(b).max()


def test_qdldl_holds_the_drape(scene_file):
    """The 32 x 32 drape at a 1 % limit with the stop-29 cloth settings (pivoted rows, smooth,
    chord): factorised by QDLDL it holds the bound the SuperLU run holds, with factorisations
    counted (the path is taken), no vertex inside the ball and no penetration."""
    pv = dict(contacts="rows", near=0.005, pivots=2, frames=8)
    ex = dict(global_tolerance=0.005, global_smooth=40, global_alpha=1e-4, global_chord=3,
              global_chord_rate=0.8, global_fast_lu=True)
    g0, g1 = [], []
    s0, d0, pen0 = _drape(scene_file, 20, calls=[], glob=g0,
                          extra=_ex(**ex, global_factor="superlu"), **pv)
    s1, d1, pen1 = _drape(scene_file, 20, calls=[], glob=g1,
                          extra=_ex(**ex, global_factor="qdldl"), **pv)
    assert g1[0].ldl and not g0[0].ldl
    assert g1[0].stats["factorisations"] > 0
    assert s0.max() < 0.0155 and s1.max() < 0.0155
    assert abs(s1.max() - s0.max()) < 0.002
    for d, pen in ((d0, pen0), (d1, pen1)):
        assert (d > 0.0).all() and (pen == 0).all()
