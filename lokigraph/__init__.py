"""lokigraph: open simulation framework for character effects."""

import os as _os
import sys as _sys
import tempfile as _tempfile

__version__ = "0.1.0"


def _numba_cache_dir() -> str:
    """Where numba keeps its compiled-kernel cache: never inside the installed package.

    numba's default (``__pycache__`` beside the source) leaves files in site-packages that pip
    does not own; an uninstall then leaves ``site-packages/lokigraph/`` behind, and that empty
    namespace package shadows a later editable install. The cache goes to ``$NUMBA_CACHE_DIR``
    if the user set it, else ``$LOKIGRAPH_CACHE_DIR/numba``, else the user cache folder
    (``$XDG_CACHE_HOME`` or ``~/.cache``)/lokigraph/numba, else a per-user temp folder.
    """
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return _os.environ["NUMBA_CACHE_DIR"]
    base = _os.environ.get("LOKIGRAPH_CACHE_DIR")
    if not base:
        xdg = _os.environ.get("XDG_CACHE_HOME") or _os.path.join(_os.path.expanduser("~"),
                                                                  ".cache")
        base = _os.path.join(xdg, "lokigraph")
    uid = getattr(_os, "getuid", lambda: 0)()
    for cand in (_os.path.join(base, "numba"),
                 _os.path.join(_tempfile.gettempdir(), f"lokigraph-{uid}", "numba")):
        try:
            _os.makedirs(cand, exist_ok=True)
        except OSError:
            continue
        if _os.access(cand, _os.W_OK | _os.X_OK):
            return cand
    return ""


_cache = _numba_cache_dir()
if _cache:
    _os.environ["NUMBA_CACHE_DIR"] = _cache
    if "numba" in _sys.modules:  # numba read its config before us: make it see the new folder
        _sys.modules["numba"].core.config.reload_config()

# Threads that never lose to one thread: numba's OpenMP layer (the one it picks when TBB is not
# installed) spin-waits at every parallel-region barrier by default. On a busy machine the spinning
# thread takes the core from the thread it waits for, and the colour-by-colour Gauss-Seidel sweeps
# (a barrier per colour) then ran 8x slower than one thread (cloth_sphere_64, 2 cores with one
# other CPU-bound process). Passive waiting sleeps at the barrier instead: measured on 2 cores,
# as fast as spinning when idle and within noise of one thread under load
# (graphs/bench/threads.md). Set before the OpenMP runtime starts; a user's setting wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "passive")
