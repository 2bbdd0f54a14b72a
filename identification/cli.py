"""The ``odocompass`` command line (SPEC §5).

Each command lives in its own module and is imported only when run, so ``--help`` is fast.
``main`` is the one place that turns errors into exit codes (issue 11):

* the project's errors (bad logs, bad parameters, unusable outputs: ``OdoCompassError``,
  ``ParameterError``) and the operating system's refusals (a file that cannot be read or
  written) print one line ``odocompass: error: ...`` and exit 2;
* anything else is a defect: one line ``odocompass: internal error: ...`` with a hint that
  ``--debug`` shows the traceback, exit 1;
* Ctrl-C exits 130;
* a fleet command returns 3 when it finished but some vehicle (or drive) ended ``error``
  (``identification.cli_fleet``); its summary names each one and why.

Common options, accepted before or after the command: ``-q/--quiet`` (no progress bars or
information lines; warnings and errors still show), ``--debug`` (tracebacks).  Progress bars
appear only when stderr is a terminal.
"""

from __future__ import annotations

import argparse
import os
import sys

EXIT_USAGE = 2
EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130

FIT_HELP = ("comma-separated parameter keys, no spaces, e.g. P,B,T_F,a; any numeric key of the parameter "
            "file (jaxmodel/params.py PARAMETER_TABLE) except sensor_axle and counter_modulus")


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every default after its help text (those that mean something: not None or False)."""

    def _get_help_string(self, action):
        if action.default in (None, False, argparse.SUPPRESS) or action.default == []:
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """A usage error is one line too: ``odocompass: error: <command>: <message>``, exit 2."""

    def error(self, message):
        command = self.prog.partition(" ")[2]
        self.exit(EXIT_USAGE, f"odocompass: error: {command + ': ' if command else ''}{' '.join(message.split())} "
                              f"(see {self.prog} --help)\n")


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("odocompass")
    except Exception:  # not installed (run from a checkout)
        return "0+unknown"


def _configure_jax():
    """float64, and compiled programs kept between runs (identification/compile_cache.py)."""
    import jax

    from . import compile_cache

    jax.config.update("jax_enable_x64", True)
    compile_cache.configure()


def _int_from(least: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be {least} or more, got {value}")
        return value
    return parse


_nonneg_int = _int_from(0)
_pos_int = _int_from(1)  # the same message whatever the value (-5 once read 'must be 0 or more')


def _number(lo: float | None = None, lo_open: bool = True, hi: float | None = None):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if value != value or value in (float("inf"), float("-inf")):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            raise argparse.ArgumentTypeError(f"must be {'above' if lo_open else 'at least'} {lo:g}, got {value:g}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"must be at most {hi:g}, got {value:g}")
        return value

    return parse


def _common() -> argparse.ArgumentParser:
    """-q and --debug, accepted after the command too (SUPPRESS keeps the top-level value)."""
    c = _Parser(add_help=False)
    c.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="no progress bars or information lines (warnings and errors still show)")
    c.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                   help="show the Python traceback of an unexpected error")
    return c


def _parser() -> argparse.ArgumentParser:
    """The whole command line: the top-level options and one subparser per command."""
    p = _Parser(
        prog="odocompass", formatter_class=_Formatter,
        description="Dead-reckoning heading estimation: odometer + compass (SPEC §5). Headings are degrees "
                    "clockwise from true north in files and on the command line; drive logs are CSV, Parquet "
                    "or MDF4 (.csv, .parquet, .mf4), chosen by extension.",
        epilog="Exit codes: 0 success, 2 bad input or unusable output (one line on stderr), 1 internal error "
               "(--debug shows the traceback), 3 a fleet command finished but some vehicle or drive ended in "
               "error (listed in its summary), 130 interrupted.")
    p.add_argument("--version", action="version", version=f"odocompass {_version()}")
    p.add_argument("-q", "--quiet", action="store_true", default=False,
                   help="no progress bars or information lines (warnings and errors still show)")
    p.add_argument("--debug", action="store_true", default=False,
                   help="show the Python traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    common = [_common()]

    def add(name, help_, description):
        return sub.add_parser(name, help=help_, description=description, parents=common, formatter_class=_Formatter)

    # the order of these calls is the order of the commands in --help and in the invalid-choice message
    _add_demo_parser(add)
    _add_simulate_parser(add)
    _add_estimate_parser(add)
    _add_identify_parser(add)
    _add_build_fmu_parser(add)
    _add_import_parser(add)
    from .cli_fleet import add_parser as add_fleet  # fleet identify / fleet evaluate (identification/cli_fleet.py)

    add_fleet(add, common, _Formatter, FIT_HELP, _pos_int, _number)
    return p


def _add_demo_parser(add) -> None:
    """``odocompass demo``; ``add(name, help, description)`` makes a command's subparser (see _parser)."""
    d = add("demo", "simulate, estimate, identify, build and co-simulate the FMU",
            "The main job on an embedded default: simulates drives, estimates the heading in every mode, "
            "identifies a vehicle's parameters, builds the estimator FMU and co-simulates it with fmpy. "
            "Everything (plots, tables, drives, FMUs) is written under --out-dir.")
    d.add_argument("--out-dir", default="build/demo", metavar="DIR", help="folder for every output of the demo")
    d.add_argument("--quick", action="store_true", help="shorter drives (about 4 minutes of driving, for tests)")


def _add_simulate_parser(add) -> None:
    """``odocompass simulate``: scenario, duration, seed, true parameters, fixes, dpp mismatch, anomalies."""
    s = add("simulate", "synthetic drive plus a truth file beside it",
            "Simulates a drive of a vehicle with wheel pulse counters and a compass, and writes DRIVE plus "
            "DRIVE-stem.truth.csv / .truth.json beside it (the truth JSON is usable as --params).")
    s.add_argument("--scenario", choices=("urban", "highway", "mixed", "parking"), default="mixed",
                   help="kind of drive")
    s.add_argument("--duration", type=_number(0.0, hi=7 * 86400.0), default=900.0, metavar="S",
                   help="drive duration, seconds")
    s.add_argument("--seed", type=_nonneg_int, default=0, metavar="N", help="random seed (0 or more)")
    s.add_argument("--out", required=True, metavar="DRIVE", help="drive file: .csv, .parquet or .mf4")
    s.add_argument("--params", metavar="P.json",
                   help="true vehicle parameters: a parameter file or a truth .json written by simulate "
                        "(default: the built-in defaults)")
    s.add_argument("--fixes-sigma", type=_number(0.0, lo_open=False), default=None, metavar="M",
                   help="add 1 Hz position fixes with this sigma per axis, metres")
    s.add_argument("--fixes-model", choices=("gnss", "white"), default=None,  # simulate.FIX_MODELS (lazy import)
                   help="fix errors: gnss = half white, half correlated over 30 s (used when omitted); "
                        "white = independent; needs --fixes-sigma")
    s.add_argument("--dpp-mismatch", type=_number(-0.5, hi=0.5), default=0.0, metavar="R",
                   help="right wheel's true distance per pulse relative excess, e.g. 0.003 (dimensionless)")
    s.add_argument("--no-anomalies", action="store_true", help="no localized magnetic anomalies")


def _add_estimate_parser(add) -> None:
    """``odocompass estimate``: the drive, parameters, output table and the estimator's switches."""
    e = add("estimate", "run the estimator on a drive log",
            "Runs the heading estimator over a drive log and writes one row per sample: time_s, heading_deg, "
            "wheel_heading_deg, compass_heading_deg (degrees, true north), x_m, y_m (metres east/north), "
            "speed_mps, a (s²/m²), heading_reliability, compass_valid, odometer_valid, dpp_ratio, curvature, "
            "effective_track_m, map_used. Output formats, by the extension of --out: .csv, .parquet (or .pq) "
            "and .mf4 (ASAM MDF4).")
    e.add_argument("drive", metavar="DRIVE", help="drive log: .csv, .parquet or .mf4")
    e.add_argument("--params", metavar="P.json",
                   help="parameter file (default: the built-in defaults); without the vehicle's own P, B, T_F, T_R, "
                        "a, dpp the wheel turn's scale error is learned online")
    e.add_argument("--out", required=True, metavar="EST",
                   help="output table: .csv, .parquet or .mf4 (format by extension); never one of the inputs")
    e.add_argument("--mode", choices=("complementary", "kalman", "odometer", "compass"), default="complementary",
                   help="heading estimator")
    e.add_argument("--calibration", choices=("on", "off"), default="on",
                   help="continuous left/right distance-per-pulse calibration (EP 0619873)")
    e.add_argument("--refine-a", choices=("on", "off"), default="on",
                   help="online refinement of the velocity coefficient a (US 4,788,645 eq. 13)")
    e.add_argument("--track", choices=("closed_form", "table"), default="closed_form",
                   help="effective track: eq. (14) or the table look-up of claims 15-16")
    e.add_argument("--filter", choices=("robust", "seed"), default="robust",
                   help="robust: odometer guard in every mode, F-DELTA by a Kalman filter with a rate state (tyre "
                        "mismatch), B_E per heading, calibration up to 3 %% (docs/tuning.md); seed: US 4,734,863's "
                        "first-order F-DELTA as first tuned on the project's simulator, for comparison")
    e.add_argument("--hard-iron", choices=("on", "off"), default="off",
                   help="online estimate of the compass offsets X0/Y0 from the field seen while turning, started "
                        "from the parameter file's X0/Y0 (jaxmodel/hard_iron.py; for a compass never calibrated: "
                        "it converges once the drive has turned through about 120 deg, docs/real-data.md)")


def _add_identify_parser(add) -> None:
    """``odocompass identify``: training and held-out drives, the keys fitted and the fit's settings."""
    i = add("identify", "identify vehicle parameters by gradient descent",
            "Fits vehicle parameters to reference headings (column ref_heading_deg, degrees) of logged drives "
            "and writes them, with a report, as a parameter file usable by estimate and build-fmu. Starting "
            "values of 0 are allowed for non-negative keys such as a.")
    i.add_argument("drives", nargs="+", metavar="DRIVE", help="training drive logs with ref_heading_deg or fixes")
    i.add_argument("--params", required=True, metavar="INIT.json",
                   help="starting parameter file (also the prior means)")
    i.add_argument("--out", required=True, metavar="FIT.json", help="fitted parameter file (JSON, with a report)")
    i.add_argument("--fit", default="P,B,T_F,a,T_C,D_N", metavar="KEYS", help=FIT_HELP)
    i.add_argument("--validate", nargs="*", default=[], metavar="DRIVE",
                   help="held-out drive logs, evaluated but never fitted")
    i.add_argument("--plots", default=None, metavar="DIR", help="folder for the report's plots (default: no plots)")
    i.add_argument("--mode", choices=("complementary", "odometer", "kalman"), default="odometer",
                   help="estimator mode whose heading is fitted (odometer: wheel parameters on the odometer "
                        "heading, then D_N and other filter keys on the complementary heading)")
    i.add_argument("--max-iter", type=_pos_int, default=400, metavar="N",
                   help="cap on iterations per stage (stops earlier on convergence)")
    i.add_argument("--refine-a", choices=("on", "off"), default="on", help="online refinement of a while fitting")
    i.add_argument("--calibration", choices=("on", "off"), default="off",
                   help="left/right dpp calibration while fitting (off: fit the raw wheel model)")
    i.add_argument("--increment-s", type=_number(0.0, lo_open=False), default=30.0, metavar="S",
                   help="odometer heading fitted as heading changes over this many seconds "
                        "(0: absolute, offset removed); against fixes the changes span 60 s")
    i.add_argument("--reference", choices=("heading", "fixes", "auto"), default="auto",
                   help="what the drives are fitted against: ref_heading_deg, the position fixes (fix_east_m, "
                        "fix_north_m, fix_valid: course of 20 s chords of the track), or auto (ref_heading_deg "
                        "when every training drive has it, else the fixes)")


def _add_build_fmu_parser(add) -> None:
    """``odocompass build-fmu``: parameters, FMU file, native or Python FMU."""
    b = add("build-fmu", "export the estimator FMU",
            "Exports the estimator as an FMI 2.0 co-simulation FMU with the parameters as start values.")
    b.add_argument("--params", default=None, metavar="P.json", help="parameter file (default: built-in defaults)")
    b.add_argument("--out", default="build/OdoCompass.fmu", metavar="FMU",
                   help="FMU file, must end in .fmu (with --native the default is build/OdoCompassNative.fmu)")
    b.add_argument("--native", action="store_true", help="Python-free C FMU")


def _add_import_parser(add) -> None:
    """``odocompass import``: source kind and path, drive file, axle and distance per pulse."""
    m = add("import", "convert a real log to the drive schema",
            "Converts a comma2k19 segment or a Husky bag into a drive log plus DRIVE-stem.params.json beside "
            "it. Sources with NaN or gaps the importer cannot bridge are refused.")
    m.add_argument("kind", choices=("comma2k19", "husky"), help="source kind")
    m.add_argument("source", help="comma2k19 segment folder or Husky .bag file")
    m.add_argument("--out", required=True, metavar="DRIVE",
                   help="drive file (.csv, .parquet or .mf4); <stem>.params.json is written beside it")
    m.add_argument("--axle", choices=("front", "rear"), default=None,
                   help="comma2k19: wheel pair integrated into pulses (front when omitted); Husky: rear only")
    m.add_argument("--dpp", type=_number(0.0, hi=10.0), default=None, metavar="M",
                   help="metres per pulse of the synthesised counters (0.02 comma2k19, 0.001 Husky when omitted)")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _os_error_line(exc: OSError) -> str:
    where = exc.filename if exc.filename is not None else None
    what = exc.strerror or _one_line(exc)
    return f"{where}: {what}" if where is not None else what


def _run(args) -> int:
    if args.command == "demo":
        from .demo import main as run
    elif args.command == "simulate":
        from .simulate import main as run
    elif args.command == "estimate":
        from .estimate import main as run
    elif args.command == "identify":
        from .identify_command import main as run
    elif args.command == "build-fmu":
        from fmu.build import main as run
    elif args.command == "fleet":
        from .cli_fleet import main as run
    else:
        from .importers import main as run
    return int(run(args) or 0)


def _command_parser(parser: argparse.ArgumentParser, args) -> argparse.ArgumentParser:
    """The parser of the (sub)command ``args`` chose, e.g. ``odocompass fleet identify``'s."""
    while True:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        chosen = getattr(args, subs[0].dest, None) if subs else None
        if chosen not in (subs[0].choices if subs else {}):
            return parser
        parser = subs[0].choices[chosen]


def main(argv=None) -> int:
    try:
        parser = _parser()
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # named by the (sub)command they were given to, as its other usage errors are
            _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(unknown)}")
    except SystemExit as exc:  # --help, --version (0) and usage errors (2, one line): returned, not raised
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    from . import console

    console.set_quiet(args.quiet)
    debug = bool(args.debug)
    try:
        _configure_jax()
        return _run(args)
    except KeyboardInterrupt:
        print("odocompass: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # the one place that maps errors to exit codes
        from jaxmodel.params import ParameterError

        from .errors import OdoCompassError

        if debug:
            import traceback

            traceback.print_exc()
        if isinstance(exc, (OdoCompassError, ParameterError)):
            print(f"odocompass: error: {_one_line(exc)}", file=sys.stderr)
            return EXIT_USAGE
        if isinstance(exc, OSError):  # a file the system refuses to read or write: the user's to fix
            print(f"odocompass: error: {_os_error_line(exc)}", file=sys.stderr)
            return EXIT_USAGE
        print(f"odocompass: internal error: {type(exc).__name__}: {_one_line(exc)[:500]}"
              + ("" if debug else " (run again with --debug for the traceback)"), file=sys.stderr)
        return EXIT_INTERNAL

def entry() -> None:
    """The ``odocompass`` console script: ``main``'s exit code.  After Ctrl-C the process leaves without the
    interpreter's finalization: XLA's compiler threads may still be running, and finalizing under them crashed the
    process (SIGSEGV instead of 130).  Outputs are already safe by then (written to a temporary file and renamed)."""
    code = main()
    if code == EXIT_INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
