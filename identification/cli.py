"""The ``odocompass`` command line (SPEC §5).

Each command lives in its own module and is imported only when run, so ``--help`` is fast.
User errors (bad logs, bad parameters) print one line ``odocompass: error: ...`` and exit 2.
"""

from __future__ import annotations

import argparse
import sys

EXIT_USAGE = 2


def _enable_x64():
    import jax

    jax.config.update("jax_enable_x64", True)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="odocompass", description="Dead-reckoning heading estimation: odometer + compass.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="simulate, estimate, identify, build and co-simulate the FMU; plots into build/demo/")
    d.add_argument("--out-dir", default="build/demo", help="where plots and tables go (default build/demo)")
    d.add_argument("--quick", action="store_true", help="shorter drives (for tests)")

    s = sub.add_parser("simulate", help="synthetic drive plus a truth file beside it")
    s.add_argument("--scenario", choices=("urban", "highway", "mixed", "parking"), default="mixed")
    s.add_argument("--duration", type=float, default=900.0, help="seconds (default 900)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, help="drive file (.csv, .parquet or .mf4)")
    s.add_argument("--params", help="true vehicle parameters (JSON); default: built-in defaults")
    s.add_argument("--fixes-sigma", type=float, default=None, metavar="M",
                   help="add 1 Hz position fixes with this sigma per axis (m)")
    s.add_argument("--fixes-model", choices=("gnss", "white"), default=None,  # simulate.FIX_MODELS (lazy import)
                   help="fix errors: gnss = half white, half correlated over 30 s (default); white = independent")
    s.add_argument("--dpp-mismatch", type=float, default=0.0, help="right wheel's true dpp relative excess, e.g. 0.003")
    s.add_argument("--no-anomalies", action="store_true", help="no localized magnetic anomalies")

    e = sub.add_parser("estimate", help="run the estimator on a drive log")
    e.add_argument("drive")
    e.add_argument("--params", help="parameter JSON (default: built-in defaults)")
    e.add_argument("--out", required=True, help="output CSV")
    e.add_argument("--mode", choices=("complementary", "kalman", "odometer", "compass"), default="complementary")
    e.add_argument("--calibration", choices=("on", "off"), default="on")
    e.add_argument("--refine-a", choices=("on", "off"), default="on")
    e.add_argument("--track", choices=("closed_form", "table"), default="closed_form")

    i = sub.add_parser("identify", help="identify vehicle parameters by gradient descent")
    i.add_argument("drives", nargs="+")
    i.add_argument("--params", required=True, help="starting parameter JSON (also the prior means)")
    i.add_argument("--out", required=True)
    i.add_argument("--fit", default="P,B,T_F,a,T_C,D_N")
    i.add_argument("--validate", nargs="*", default=[])
    i.add_argument("--plots", default=None, metavar="DIR")
    i.add_argument("--mode", choices=("complementary", "odometer", "kalman"), default="odometer",
                   help="estimator mode whose heading is fitted (default odometer: wheel parameters on the "
                        "odometer heading, then D_N and other filter keys on the complementary heading)")
    i.add_argument("--max-iter", type=int, default=400, help="cap on iterations per stage (stops earlier on convergence)")
    i.add_argument("--refine-a", choices=("on", "off"), default="on", help="online refinement of a while fitting")
    i.add_argument("--calibration", choices=("on", "off"), default="off",
                   help="left/right dpp calibration while fitting (default off: fit the raw wheel model)")
    i.add_argument("--increment-s", type=float, default=30.0,
                   help="odometer heading fitted as heading changes over this many seconds (0: absolute, offset removed)")

    b = sub.add_parser("build-fmu", help="export the estimator FMU")
    b.add_argument("--params", default=None)
    b.add_argument("--out", default="build/OdoCompass.fmu")
    b.add_argument("--native", action="store_true", help="Python-free C FMU (default --out build/OdoCompassNative.fmu)")

    m = sub.add_parser("import", help="convert a real log to the drive schema")
    m.add_argument("kind", choices=("comma2k19", "husky"))
    m.add_argument("source", help="comma2k19 segment folder or Husky .bag file")
    m.add_argument("--out", required=True, help="drive file; <stem>.params.json is written beside it")
    m.add_argument("--axle", choices=("front", "rear"), default=None,
                   help="comma2k19: wheel pair integrated into pulses (default front); Husky: rear only")
    m.add_argument("--dpp", type=float, default=None, metavar="M",
                   help="metres per pulse of the synthesised counters (default 0.02 comma2k19, 0.001 Husky)")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    _enable_x64()
    from .errors import OdoCompassError
    from jaxmodel.params import ParameterError

    try:
        if args.command == "demo":
            from .demo import main as run
        elif args.command == "simulate":
            from .simulate import main as run
        elif args.command == "estimate":
            from .estimate import main as run
        elif args.command == "identify":
            from .identify import main as run
        elif args.command == "build-fmu":
            from fmu.build import main as run
        else:
            from .importers import main as run
        return int(run(args) or 0)
    except (OdoCompassError, ParameterError) as exc:
        print(f"odocompass: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("odocompass: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
