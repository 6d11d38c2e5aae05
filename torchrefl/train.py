"""python -m torchrefl.train CONFIG [dotted.key=value ...] [--overwrite] [--resume] [--quiet]  |  --list

CONFIG is a YAML file or the name of a bundled config (`default`; --list prints them).

The command line of torchrefl.run: one config (and dotted overrides) -> one run folder, written whole or
not at all (torchrefl.report.run_folder). Streams: the summary table and the run folder's path on stdout;
log lines, progress bars and errors on stderr (--quiet: errors only). Exit status: 0 done, 2 a named error
or a usage error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys

from torchrefl.config import describe, load_config
from torchrefl.config_bundle import listing
from torchrefl.errors import command_status
from torchrefl.report.run_folder import output_folder
from torchrefl.report.summary import summary_table
from torchrefl.run import run

PROG = "python -m torchrefl.train"
USAGE = f"{PROG} CONFIG [dotted.key=value ...] [--overwrite] [--resume] [--quiet]"
NO_CONFIG = (
    "CONFIG is missing: give a YAML config file (e.g. configs/default.yaml) or the name of a bundled config "
    f"(e.g. default; {PROG} --list lists them), then any dotted.key=value overrides; {PROG} --help lists every "
    "option"
)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog=PROG,
        usage=USAGE,
        description="Estimate Pd, Ps, sigma maps from a capture described by CONFIG.",
        epilog="Options (set in the YAML file or as dotted.key=value overrides):\n" + "\n".join(describe()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "config",
        nargs="?",
        metavar="CONFIG",
        help="YAML config file (e.g. configs/default.yaml) or the name of a bundled config (e.g. default; see --list)",
    )
    parser.add_argument(
        "overrides", nargs="*", help="dotted.key=value overrides, e.g. output.dir=/tmp/x fit.holdout=[5,11]"
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no log lines and no progress bars on stderr (log.txt is still written); the summary and errors stay",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier run in output.dir (kept until this run completes; without the flag "
        "a folder holding a run is refused)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the newest unfinished (killed or failed) run of this config into output.dir from its last "
        "checkpoint (after each stage and each photon outer iteration); the log says which; none: start anew",
    )
    parser.add_argument("--list", action="store_true", help="print the bundled configs and exit")
    args = parser.parse_intermixed_args(argv)
    if args.list:
        print(listing())
        return 0
    if args.config is None:
        print(f"usage: {USAGE}", file=sys.stderr)
        print(f"torchrefl: error: {NO_CONFIG}", file=sys.stderr)
        return 2

    def work() -> int:
        cfg = load_config(args.config, args.overrides)
        metrics = run(cfg, quiet=args.quiet, overwrite=args.overwrite, resume=args.resume)
        print(summary_table(metrics))
        print(f"\nrun folder: {output_folder(cfg.output.dir)}")
        return 0

    return command_status(work)


if __name__ == "__main__":
    sys.exit(main())
