"""Solvers, one folder each: ``nucleus/`` (symplectic Euler with interleaved Gauss-Seidel
constraint projection, XPBD). A solver is generic over the contributions of the material,
attachment, collision and air modules."""
