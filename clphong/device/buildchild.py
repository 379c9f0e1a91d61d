"""The compiling child of :mod:`clphong.device.isolate`: ``python -m clphong.device.buildchild
--device P:D`` reads one JSON request a line on stdin ({"entry", "opts", "out"}), compiles
in-process and writes the program's binary to ``out``, and answers one JSON line
({"error": ""} or the compiler's first error line)."""

from __future__ import annotations

import argparse
import json
import sys

from ..core.errors import DeviceError
from .selection import get_runtime


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clphong.device.buildchild")
    p.add_argument("--device", required=True)
    args = p.parse_args(argv)
    rt = get_runtime(args.device)
    for line in sys.stdin:
        req = json.loads(line)
        try:
            rt.compile_to(req["entry"], req["opts"], req["out"])
            answer = {"error": ""}
        except DeviceError as exc:
            answer = {"error": (str(exc).splitlines() or [type(exc).__name__])[0]}
        sys.stdout.write(json.dumps(answer) + "\n")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
