"""python -m torchrefl.batch BATCH.yaml [--address ADDR] [--num-cpus N] [--quiet]

Fits every capture of the batch file on Ray (docs/batch.md): Ray starts on this machine, or joins the cluster at
--address. Streams: a progress bar (done / failed / running) on stderr, the summary path and, last, how many
captures failed on stdout. Exit status: 0 every capture complete, 1 some failed, 2 a bad batch file or no Ray.
"""

from __future__ import annotations

import argparse
import sys

from torchrefl.batch.batch_file import read_batch
from torchrefl.batch.runner import run_batch
from torchrefl.batch.summary import CSV, JSON, last_line
from torchrefl.errors import command_status

PROG = "python -m torchrefl.batch"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Fit many captures (a batch file: base, captures, synthetic_seeds, overrides, output) on Ray.",
    )
    parser.add_argument("batch", metavar="BATCH.yaml", help="the batch file (docs/batch.md lists its keys)")
    parser.add_argument(
        "--address", help="a running Ray cluster to join (e.g. HEAD:6379; default: start Ray on this machine)"
    )
    parser.add_argument(
        "--num-cpus", type=int, help="CPUs a Ray started here offers (default: all): concurrent fits x cpus_per_task"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    def work() -> int:
        batch = read_batch(args.batch)
        rows = run_batch(batch, args.address, args.num_cpus, progress=not args.quiet)
        print(f"summary: {batch.output / JSON} and {CSV}")
        print(last_line(rows))
        return 0 if all(r.done for r in rows) else 1

    return command_status(work)


if __name__ == "__main__":
    sys.exit(main())
