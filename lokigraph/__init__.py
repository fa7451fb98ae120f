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
    (``$XDG_CACHE_HOME`` or ``~/.cache``)/lokigraph/numba, else a per-user temp folder; in
    the last three, in a subfolder per state of lokigraph's sources (``_source_stamp``).
    """
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return _os.environ["NUMBA_CACHE_DIR"]
    base = _os.environ.get("LOKIGRAPH_CACHE_DIR")
    if not base:
        xdg = _os.environ.get("XDG_CACHE_HOME") or _os.path.join(_os.path.expanduser("~"),
                                                                  ".cache")
        base = _os.path.join(xdg, "lokigraph")
    uid = getattr(_os, "getuid", lambda: 0)()
    stamp = _source_stamp()
    for root in (_os.path.join(base, "numba"),
                 _os.path.join(_tempfile.gettempdir(), f"lokigraph-{uid}", "numba")):
        cand = _os.path.join(root, stamp)
        try:
            _os.makedirs(cand, exist_ok=True)
        except OSError:
            continue
        if _os.access(cand, _os.W_OK | _os.X_OK):
            _prune(root, stamp)
            return cand
    return ""


def _source_stamp() -> str:
    """A stamp of the state of lokigraph's Python sources (path, size and modification time of
    every ``.py`` file of lokigraph, lokigraph.behaviors and lokigraph.components).

    numba's cache checks only the source file of the function it compiled: a kernel that
    inlines or calls a function of another file keeps that function's old code after the other
    file changes (a kernel of strain_limit_global.py ran the previous ``limit_edge`` of
    strain_limit.py after an edit). Kernels compiled from one state of the sources go to a
    folder of their own, so an edit or an upgrade compiles everything again once."""
    import hashlib
    import importlib.util

    h = hashlib.sha1(__version__.encode())
    here = _os.path.dirname(_os.path.abspath(__file__))
    roots = [here]
    for sub in ("lokigraph.behaviors", "lokigraph.components"):
        try:
            spec = importlib.util.find_spec(sub)
        except (ImportError, ValueError):
            spec = None
        for loc in (spec.submodule_search_locations or []) if spec else []:
            loc = _os.path.abspath(loc)
            if not loc.startswith(here + _os.sep):
                roots.append(loc)
    for root in roots:
        for d, dirs, files in _os.walk(root):
            dirs[:] = sorted(x for x in dirs if x != "__pycache__")
            for name in sorted(files):
                if name.endswith(".py"):
                    p = _os.path.join(d, name)
                    try:
                        st = _os.stat(p)
                    except OSError:
                        continue
                    h.update(f"{p}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
    return h.hexdigest()[:16]


#: cache folders of other source states unused for this long are removed [s]
_CACHE_KEEP_S = 7 * 24 * 3600


def _prune(root: str, keep: str) -> None:
    """Remove the entries of ``root`` other than ``keep`` not modified for ``_CACHE_KEEP_S``
    (kernels of earlier source states, and the per-folder layout before the stamps)."""
    import shutil
    import time

    try:
        names = _os.listdir(root)
    except OSError:
        return
    old = time.time() - _CACHE_KEEP_S
    for name in names:
        p = _os.path.join(root, name)
        try:
            if name != keep and _os.stat(p).st_mtime < old:
                shutil.rmtree(p, ignore_errors=True)
        except OSError:
            continue


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
