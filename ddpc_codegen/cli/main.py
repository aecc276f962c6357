"""``ddpc-codegen`` console command.

Each feature module contributes its subcommands through a ``register(subparsers)`` function;
they are listed in ``_COMMAND_MODULES`` so the CLI reads like the package layout.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ddpc_codegen.errors import DDPCError

# module path -> registers its subcommands (add one line per feature module)
_COMMAND_MODULES: tuple[str, ...] = (
    "ddpc_codegen.cli.sim",
    "ddpc_codegen.cli.logs",
    "ddpc_codegen.cli.codegen",
    "ddpc_codegen.cli.fit",
    "ddpc_codegen.cli.front",
    "ddpc_codegen.cli.sweep",
    "ddpc_codegen.experiments.demo",
    "ddpc_codegen.experiments.adapt_eval",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ddpc-codegen",
        description="Reference steering via data-driven predictive control: data -> predictor -> generated C solver.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:  # an optional extra is not installed
            raise SystemExit(f"ddpc-codegen: {name} needs the Python package {e.name!r}; install the extras "
                             "with `pip install 'ddpc-codegen[all]'`") from None
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DDPCError as e:
        print(f"ddpc-codegen {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
