"""python -m torchrefl.train CONFIG [dotted.key=value ...] [--overwrite] [--quiet]  |  --list

CONFIG is a YAML file or the name of a bundled config (`default`; --list prints them).

The command line of torchrefl.run: one config (and dotted overrides) -> one run folder, written whole or
not at all (torchrefl.report.run_folder). Exit status: 0 done, 2 a named error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys

from torchrefl.config import describe, load_config
from torchrefl.config_bundle import listing
from torchrefl.errors import command_status
from torchrefl.report.summary import summary_table
from torchrefl.run import run


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m torchrefl.train",
        description="Estimate Pd, Ps, sigma maps from a capture described by CONFIG.",
        epilog="Options (set in the YAML file or as dotted.key=value overrides):\n" + "\n".join(describe()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "config",
        nargs="?",
        help="YAML config file (e.g. configs/default.yaml) or the name of a bundled config (e.g. default; see --list)",
    )
    parser.add_argument(
        "overrides", nargs="*", help="dotted.key=value overrides, e.g. output.dir=/tmp/x fit.holdout=[5,11]"
    )
    parser.add_argument("--quiet", action="store_true", help="no log lines on stderr (log.txt is still written)")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier run in output.dir (kept until this run completes; without the flag "
        "a folder holding a run is refused)",
    )
    parser.add_argument("--list", action="store_true", help="print the bundled configs and exit")
    args = parser.parse_intermixed_args(argv)
    if args.list:
        print(listing())
        return 0
    if args.config is None:
        parser.error("the following arguments are required: config (a YAML file, or a bundled name: --list)")

    def work() -> int:
        metrics = run(load_config(args.config, args.overrides), quiet=args.quiet, overwrite=args.overwrite)
        if args.quiet:
            print(summary_table(metrics))
        return 0

    return command_status(work)


if __name__ == "__main__":
    sys.exit(main())
