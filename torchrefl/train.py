"""python -m torchrefl.train CONFIG [dotted.key=value ...] [--overwrite] [--quiet]

The command line of torchrefl.run: one config (and dotted overrides) -> one run folder, written whole or
not at all (torchrefl.report.run_folder). Streams: the summary table and the run folder's path on stdout;
log lines, progress bars and errors on stderr (--quiet: errors only). Exit status: 0 done, 2 a named error
or a usage error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys

from torchrefl.config import describe, load_config
from torchrefl.errors import TorchReflError
from torchrefl.report.run_folder import output_folder
from torchrefl.report.summary import summary_table
from torchrefl.run import run

PROG = "python -m torchrefl.train"
USAGE = f"{PROG} CONFIG [dotted.key=value ...] [--overwrite] [--quiet]"
NO_CONFIG = (
    "CONFIG is missing: give a YAML config file (e.g. configs/default.yaml) or the name of a bundled config "
    f"(e.g. default; {PROG} --list lists them), then any dotted.key=value overrides; {PROG} --help lists every "
    "option"
)


def _error(text: str, notes=()) -> None:
    """An error on stderr, once: the message, then the notes the run added (where its files are)."""
    print(f"torchrefl: {text}", file=sys.stderr)
    for note in notes:
        print(f"  {note}", file=sys.stderr)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog=PROG,
        usage=USAGE,
        description="Estimate Pd, Ps, sigma maps from a capture described by CONFIG.",
        epilog="Options (set in the YAML file or as dotted.key=value overrides):\n" + "\n".join(describe()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("config", nargs="?", metavar="CONFIG", help="YAML config file (e.g. configs/default.yaml)")
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
    args = parser.parse_intermixed_args(argv)
    if args.config is None:
        print(f"usage: {USAGE}", file=sys.stderr)
        _error(f"error: {NO_CONFIG}")
        return 2
    try:
        cfg = load_config(args.config, args.overrides)
        metrics = run(cfg, quiet=args.quiet, overwrite=args.overwrite)
    except TorchReflError as exc:
        _error(f"error: {exc}", getattr(exc, "__notes__", ()))
        return 2
    except KeyboardInterrupt as exc:
        _error("interrupted", getattr(exc, "__notes__", ()))
        return 130
    print(summary_table(metrics))
    print(f"\nrun folder: {output_folder(cfg.output.dir)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
