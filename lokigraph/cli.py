"""The ``lokigraph`` command line.

Exit codes:

- 0 success;
- 2 invalid input (YAML, components, graph, ``--frames`` outside the scene's range), or an
  output location found unusable before running: ``--out`` is a file, an element folder is a
  file, a folder cannot be created or written, or it holds another run's output (give
  ``--overwrite``);
- 3 simulation failure (a non-finite value), or a write failure during the run (disk full,
  permission lost);
- 130 interrupted by Ctrl-C (SIGINT), 143 terminated by SIGTERM: the frame being written is
  finished or discarded, and ``run.json`` is written with status ``interrupted``;
- 1 anything unexpected (a bug: the traceback is printed).

Errors other than 1 are reported without a traceback; ``run.json`` records ``ok``, ``failed`` or
``interrupted`` for every run that started.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import traceback

from .errors import (EXIT_OK, EXIT_SIMULATION, EXIT_UNEXPECTED, InputError, LokigraphError,
                     OutputError)


def _frames(text: str) -> tuple[int, int]:
    try:
        a, b = text.split(":")
        return int(a), int(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (two frame numbers), got {text!r}") \
            from None


def _ints(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N,N,... (integers), got {text!r}") from None


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lokigraph", description="Cloth, hair and coupled "
                                "simulation driven by a behavior graph.")
    p.add_argument("--version", action="version", version=f"lokigraph {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a scene and write frames")
    r.add_argument("scene")
    r.add_argument("--frames", type=_frames, help="write frames A:B (simulates from the start)")
    r.add_argument("--out", help="output folder (default: the scene's output.dir)")
    r.add_argument("--format", choices=["obj", "ply", "vtu", "usd"],
                   help="format of frames: a mesh file per element per frame (obj, ply, vtu) or "
                        "one USD stage per run (usd: DIR/run.usd; needs lokigraph[usd])")
    r.add_argument("--quiet", action="store_true", help="no progress output on stderr (a bar "
                   "with frame, ms/frame and ETA on a terminal, plain lines otherwise)")
    r.add_argument("-v", "--verbose", action="store_true", help="print one line of solver "
                   "statistics per substep on stderr (also with --quiet)")
    r.add_argument("--preview", action="store_true", help="at the end, write OUT/preview.gif "
                   "and OUT/run_stats.png (lokigraph preview; needs lokigraph[preview])")
    r.add_argument("--resume", metavar="OUT", help="continue the killed, failed or interrupted "
                   "run in OUT from its last checkpoint (OUT/checkpoints; output."
                   "checkpoint_every), with the same scene; frames after it are rewritten, "
                   "bit-identical to an uninterrupted run")
    r.add_argument("--overwrite", action="store_true", help="replace another run's output in the "
                   "folder (default: the scene's output.overwrite; without it such a run is "
                   "refused)")

    v = sub.add_parser("validate", help="check a scene (everything compile checks), no run")
    v.add_argument("scene")

    pl = sub.add_parser("plan", help="print the compiled schedule and what was pruned, and why")
    pl.add_argument("scene")
    pl.add_argument("--json", action="store_true")

    sub.add_parser("behaviors", help="list registered behaviors and components")

    bn = sub.add_parser("bench", help="time per frame and error over a grid of settings")
    bn.add_argument("scene", nargs="?", help="bench scene (not needed with --scaling)")
    bn.add_argument("--sweep", action="append", default=[],
                    help="KEY=V1,V2,... (substeps, iterations, solver, graph or node.param)")
    bn.add_argument("--frames", type=int, help="frames per run, the first is warm-up (default: "
                    "the scene's frame range)")
    bn.add_argument("--repeats", type=int, default=1, help="runs per setting (median over all)")
    bn.add_argument("--reference", help="KEY=V,... setting of a tight reference run (scenes "
                    "without a reference block)")
    bn.add_argument("--make-reference", action="store_true", help="compute and store the "
                    "scene's stored reference at its reference settings")
    bn.add_argument("--scaling", action="store_true", help="cloth drape 32x32..256x256: time "
                    "per frame against vertex count, fitted exponent, memory per vertex")
    bn.add_argument("--sizes", type=_ints, default="32,64,128,256",
                    help="--scaling grid resolutions")
    bn.add_argument("--fluid", type=int, metavar="N", help="time the pressure solve of an N^3 "
                    "fluid grid (AMG-, Jacobi- and plain CG, interleaved; writes fluid.json)")
    bn.add_argument("--out", default="bench_out", help="folder for bench.csv/json/png")

    stz = sub.add_parser("stress", help="cases built to break the solver; pass/fail each")
    stz.add_argument("--quick", action="store_true", help="small and short (for CI)")
    stz.add_argument("--out", help="folder for stress.json")
    stz.add_argument("--only", help="run only the cases whose name contains this text")
    stz.add_argument("--solver", choices=("nucleus", "implicit"), default="nucleus",
                     help="solver every case's scene runs (solver: in the scene; default nucleus)")

    from .wedge import add_parser as _add_wedge

    _add_wedge(sub)

    from .preview import add_parser as _add_preview

    _add_preview(sub)

    sc = sub.add_parser("schema", help="JSON schema of components and behavior parameters")
    sc.add_argument("--out", help="write to this file instead of stdout")
    return p


def _version() -> str:
    from . import __version__

    return __version__


EXIT_SIGINT = 128 + signal.SIGINT    # 130
EXIT_SIGTERM = 128 + signal.SIGTERM  # 143


def _on_sigterm(signum, _frame):
    from .run import RunInterrupted

    raise RunInterrupted(signum)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    # SIGTERM becomes a clean interruption (like Ctrl-C), restored on return
    old = None
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        old = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main(args)
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def _main(args) -> int:
    try:
        return _dispatch(args)
    except LokigraphError as exc:
        msg = f"error: {exc}" if not isinstance(exc, InputError) else str(exc)
        res = getattr(exc, "result", None)
        if res is not None and res.out_dir is not None:
            msg += f"; kept {res.summary()}"
        print(msg, file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # output piped into e.g. `head`
        return EXIT_OK
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        what = "interrupted" if signum == signal.SIGINT else \
            f"terminated ({signal.Signals(signum).name})"
        res = getattr(exc, "result", None)
        if res is not None and res.out_dir is not None:
            print(f"{what}: kept {res.summary()}", file=sys.stderr)
        else:
            print(f"{what}; frames written so far are kept", file=sys.stderr)
        return 128 + signum
    except Exception:  # noqa: BLE001 - a bug: show everything
        traceback.print_exc()
        print("lokigraph: unexpected internal error (exit 1); please report it with the "
              "traceback above", file=sys.stderr)
        return EXIT_UNEXPECTED


def _dispatch(args) -> int:
    if args.command == "wedge":
        from .wedge import dispatch

        return dispatch(args)
    if args.command == "preview":
        from .preview import dispatch as _preview

        return _preview(args)
    if args.command == "behaviors":
        return _cmd_behaviors()
    if args.command == "schema":
        from .schema import export_schema

        text = json.dumps(export_schema(), indent=1)
        if args.out:
            from pathlib import Path

            from .run import atomic_write

            try:
                atomic_write(Path(args.out), lambda p: p.write_text(text))
            except OSError as exc:
                raise OutputError(f"cannot write {args.out}: {exc.strerror or exc}") from None
        else:
            print(text)
        return EXIT_OK
    if args.command == "stress":
        from pathlib import Path

        from .bench.stress import format_rows, run_stress

        try:
            rows = run_stress(args.quick, Path(args.out) if args.out else None, args.only,
                              progress=lambda r: print(format_rows([r]), flush=True),
                              solver=args.solver)
        except ValueError as exc:
            raise InputError(f"stress: {exc}") from None
        except OSError as exc:
            raise OutputError(f"stress: cannot write results: {_os_message(exc)}") from None
        failed = [r for r in rows if not r["passed"]]
        print(f"{len(rows) - len(failed)}/{len(rows)} cases passed")
        return EXIT_OK if not failed else EXIT_SIMULATION
    if args.command == "bench":
        try:
            return _bench(args)
        except OSError as exc:
            raise OutputError(f"bench: cannot write results: {_os_message(exc)}") from None
    from .api import compile_file

    compiled = compile_file(args.scene)
    if args.command == "validate":
        from .run import output_elements

        output_elements(compiled)  # output.elements names real elements with geometry
        n = len(compiled.scene.elements)
        print(f"{args.scene}: ok ({n} elements, {compiled.model.particle_count} vertices, "
              f"{len(compiled.schedule.all())} behaviors scheduled, "
              f"{len(compiled.schedule.pruned)} pruned)")
        return EXIT_OK
    if args.command == "plan":
        if args.json:
            print(json.dumps(compiled.schedule.as_dict(), indent=1))
        else:
            print(compiled.schedule.format())
        return EXIT_OK
    if args.command == "run":
        from .run import run

        if args.preview:  # fail before simulating when the preview extra is missing
            from .preview import check_available

            check_available("gif")
        if args.resume and args.out and args.out != args.resume:
            raise InputError("give --resume OUT or --out DIR, not both (--resume writes into "
                             "the run's own folder)")
        if args.resume and args.overwrite:
            raise InputError("--resume continues the run in OUT; --overwrite would replace it")
        res = run(compiled, frames=args.frames, out_dir=args.resume or args.out, fmt=args.format,
                  progress=not args.quiet, overwrite=True if args.overwrite else None,
                  verbose=args.verbose, resume=bool(args.resume))
        tot = sum(res.frame_seconds)
        print(f"wrote {res.summary()} ({tot:.2f} s wall time, "
              f"{tot / max(len(res.frame_seconds), 1) * 1e3:.1f} ms/frame)")
        if args.preview:
            from .preview import preview_after_run

            print("wrote " + ", ".join(map(str, preview_after_run(res.out_dir))))
        return EXIT_OK
    raise InputError(f"unknown command {args.command}")  # pragma: no cover


def _cmd_behaviors() -> int:
    from .behavior import ConstraintBehavior
    from .registry import get_registry

    reg = get_registry()
    print("behaviors:")
    for name in sorted(reg.behaviors):
        cls = reg.behaviors[name]
        req = " + ".join(t.type_id() for t in cls.requires) or ("always" if cls.always else "-")
        extra = " constraint" if issubclass(cls, ConstraintBehavior) else ""
        print(f"  {name:28s} stage={cls.stage:11s} requires={req:28s} "
              f"from={reg.source.get(name, '?')}{extra}")
    print("components:")
    for name in sorted(reg.components):
        print(f"  {name:28s} from={reg.source.get(name, '?')}")
    for ep, (dist, exc) in sorted(reg.broken.items()):
        print(f"broken plugin {ep} (distribution {dist}): {type(exc).__name__}: {exc}")
    return EXIT_OK




def _os_message(exc: OSError) -> str:
    return f"{exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else "")


def _bench(args) -> int:
    from pathlib import Path

    from .bench.sweep import format_table, make_reference, run_bench, run_scaling

    out = Path(args.out)
    if args.fluid is not None:
        import json

        from .bench.fluid import bench_pressure, format_pressure

        if not 4 <= args.fluid <= 256:
            raise InputError(f"bench --fluid {args.fluid}: give a grid size from 4 to 256")
        rows = bench_pressure(args.fluid, max(args.repeats, 1))
        print(format_pressure(rows, args.fluid, max(args.repeats, 1)))
        out.mkdir(parents=True, exist_ok=True)
        (out / "fluid.json").write_text(json.dumps(rows, indent=1))
        print(f"(results in {out}/fluid.json)")
        return EXIT_OK
    if args.scaling:
        res = run_scaling(out, args.sizes)
        print(format_table(res["rows"]))
        print(f"time per frame ~ vertices^{res['exponent']:.2f} ({res['substeps']} substeps x "
              f"{res['iterations']} iterations; results in {out}/scaling.json)")
        return EXIT_OK
    if not args.scene:
        raise InputError("bench: give a scene (or --scaling)")
    try:
        if args.make_reference:
            dest = make_reference(args.scene)
            print(f"wrote {dest}")
            return EXIT_OK
        sweeps = {}
        for sw in args.sweep or ["substeps=4"]:
            k, _, v = sw.partition("=")
            if not v:
                raise InputError(f"--sweep {sw!r}: expected KEY=V1,V2")
            sweeps[k] = v.split(",")
        ref = None
        if args.reference:
            ref = dict(x.split("=") for x in args.reference.split(","))
        rows = run_bench(args.scene, sweeps, args.frames, out, ref, args.repeats)
    except (ValueError, FileNotFoundError) as exc:
        raise InputError(f"{args.scene}: bench: {exc}") from None
    print(format_table(rows))
    print(f"(results in {out}/bench.csv, bench.json, bench.png; pareto = fastest setting for its "
          f"error level)")
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
