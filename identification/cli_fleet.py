"""The ``odocompass fleet`` command line: ``fleet identify`` and ``fleet evaluate`` (docs/fleet.md).

``add_parser(add)`` registers ``fleet`` with its two subcommands through the ``add`` helper of
``identification.cli`` (same formatter, same -q/--debug); ``main(args)`` runs the chosen one.
Errors go through ``cli.main``'s one mapping (bad input: exit 2; defect: exit 1); a fleet in
which some vehicle (identify) or drive (evaluate) ended ``error`` returns exit code 3.
"""

from __future__ import annotations


EXIT_SOME_FAILED = 3
MANIFEST_HELP = ("CSV or Parquet table with columns vehicle_id, path, role (train or validate); relative paths "
                 "are relative to the manifest's folder")


def _ray_options(p, int_type) -> None:
    p.add_argument("--address", default=None, metavar="ADDRESS",
                   help="an existing Ray cluster (e.g. auto, or ray://head:10001); default: start a local one on "
                        "this machine's cores")
    p.add_argument("--workers", type=int_type, default=None, metavar="N",
                   help="parallel tasks, one CPU and one XLA thread each (default: every CPU of the cluster)")


def add_parser(add, common: list, formatter, fit_help: str, pos_int, number) -> None:
    """Register ``fleet identify`` and ``fleet evaluate``: ``add`` is cli._parser's helper, ``common``
    its parent parsers (-q, --debug), ``formatter`` its help formatter."""

    f = add("fleet", "identify or evaluate many vehicles on Ray",
            "Fleet commands on Ray (a local cluster by default). Exit codes: 0 every vehicle ok or warning, "
            "3 some vehicle (identify) or drive (evaluate) ended error (see DIR/summary.csv), 2 bad input, "
            "1 internal error.")
    sub = f.add_subparsers(dest="fleet_command", required=True, metavar="FLEET_COMMAND")

    def sub_add(name, help_, description):
        return sub.add_parser(name, help=help_, description=description, parents=common, formatter_class=formatter)

    i = sub_add("identify", "identify every vehicle of a manifest",
                "Fits each vehicle's parameters as `odocompass identify` does, several vehicles per Ray task in one "
                "vmapped program. Writes DIR/<vehicle_id>.json (parameters + report, usable by estimate and "
                "build-fmu), DIR/summary.csv and DIR/summary.parquet (one row per vehicle: status ok/warning/error, "
                "each fitted parameter and its standard error, RMSE before/after, warnings or the error) and "
                "DIR/parameters.png. Rerunning with the same --out skips finished vehicles. Exit 3 when some "
                "vehicle ended error.")
    i.add_argument("manifest", metavar="MANIFEST", help=MANIFEST_HELP)
    i.add_argument("--params", required=True, metavar="INIT.json", help="starting parameter file (the prior means)")
    i.add_argument("--out", required=True, metavar="DIR", help="output folder")
    i.add_argument("--fit", default="P,B,T_F,a,T_C,D_N", metavar="KEYS", help=fit_help)
    _ray_options(i, pos_int)
    i.add_argument("--batch", type=pos_int, default=8, metavar="V",
                   help="vehicles per task (fitted together in one vmapped program)")
    i.add_argument("--mode", choices=("complementary", "odometer", "kalman"), default="odometer",
                   help="estimator mode whose heading is fitted (as identify --mode)")
    i.add_argument("--optimizer", choices=("gauss-newton", "lbfgs"), default="gauss-newton",
                   help="search direction: Gauss-Newton (forward-mode GN Hessian) or identify's L-BFGS")
    i.add_argument("--max-iter", type=pos_int, default=400, metavar="N", help="cap on iterations per stage")
    i.add_argument("--refine-a", choices=("on", "off"), default="on", help="online refinement of a while fitting")
    i.add_argument("--calibration", choices=("on", "off"), default="off",
                   help="left/right dpp calibration while fitting (off: fit the raw wheel model)")
    i.add_argument("--increment-s", type=number(0.0, lo_open=False), default=30.0, metavar="S",
                   help="odometer heading fitted as heading changes over this many seconds")

    e = sub_add("evaluate", "estimate every drive of a manifest, metrics to Parquet",
                "Runs the estimator over every drive of the manifest with its vehicle's parameters (one file for "
                "all, or DIR/<vehicle_id>.json from fleet identify) and writes DIR/metrics.parquet: one row per "
                "drive with heading RMSE against ref_heading_deg where present, distance, skipped samples, status "
                "and error. Exit 3 when some drive ended error.")
    e.add_argument("manifest", metavar="MANIFEST", help=MANIFEST_HELP + " (role optional here)")
    e.add_argument("--params", required=True, metavar="P.json|DIR",
                   help="one parameter file for every vehicle, or a folder of <vehicle_id>.json")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder")
    e.add_argument("--mode", choices=("complementary", "kalman", "odometer", "compass"), default="complementary",
                   help="heading estimator")
    e.add_argument("--calibration", choices=("on", "off"), default="on", help="left/right dpp calibration")
    e.add_argument("--refine-a", choices=("on", "off"), default="on", help="online refinement of a")
    e.add_argument("--track", choices=("closed_form", "table"), default="closed_form", help="effective track")
    _ray_options(e, pos_int)
    e.add_argument("--batch", type=pos_int, default=64, metavar="D", help="drives per task")


def main(args) -> int:
    if args.fleet_command == "identify":
        from .fleet_identify import main as run
    else:
        from .fleet_evaluate import main as run
    return int(run(args) or 0)
