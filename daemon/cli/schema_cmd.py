"""``climbd schema``: write the JSON Schema of every wire message, for third-party clients."""

from __future__ import annotations

import argparse
import json
import sys

from climbd.daemon.contract.messages import json_schemas


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", help="file to write (default: standard output)")


def main(args: argparse.Namespace) -> int:
    text = json.dumps(json_schemas(), indent=2, sort_keys=True)
    if args.output:
        with open(args.output, "w") as f:
            f.write(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    return 0
