"""torchrefl COMMAND [ARGS ...]: the console command installed with the package (`torchrefl train default`).

Each subcommand is its `python -m torchrefl.X` module: the dispatcher imports that module and hands it the rest
of the command line unchanged, so `torchrefl train ...` and `python -m torchrefl.train ...` are one
implementation with one set of options and exit codes.
"""

from __future__ import annotations

import importlib
import sys

from torchrefl.version import __version__

#: subcommand -> (module whose main(argv) runs it, one-line description); a new command is one more entry
COMMANDS = {
    "train": ("torchrefl.train", "fit a config (a YAML file or a bundled name such as default) into a run folder"),
    "plan": ("torchrefl.plan", "choose the light positions for a config's object and write the rig's capture plan"),
    "render": ("torchrefl.render", "relight a finished run: its image from a camera under a light, or a turntable"),
    "rig": ("torchrefl.rig.__main__", "drive the GRBL light gantry: probe, home, move, capture (or --dry-run)"),
    "batch": ("torchrefl.batch.__main__", "fit many captures (a batch file) as Ray tasks, here or on a cluster"),
}


def usage() -> str:
    """The top-level help: the subcommands and what each does."""
    width = max(len(name) for name in COMMANDS)
    lines = [
        "usage: torchrefl COMMAND [ARGS ...]",
        "",
        "Dense reflectance estimation (Pd, Ps, sigma per texel) by inverse rendering.",
        "",
        "commands (each is also `python -m MODULE`; `torchrefl COMMAND --help` for its options):",
        *(f"  {name:<{width}}  {doc}" for name, (_, doc) in COMMANDS.items()),
        "",
        "options:",
        "  -h, --help     show this message and exit",
        "  --version      print the version and exit",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    """Run `torchrefl COMMAND ARGS`: the command's main(ARGS) and its exit status; 2 for a missing or unknown one."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(usage(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if argv[0] == "--version":
        print(f"torchrefl {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"torchrefl: error: unknown command '{name}'; expected one of: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    return importlib.import_module(COMMANDS[name][0]).main(rest)


if __name__ == "__main__":
    sys.exit(main())
