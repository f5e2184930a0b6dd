"""Where the suite's time compiling goes: sums the logs a run writes with
FOVJAX_TEST_COMPILE_LOG=DIR (tests/conftest.py) by test file and by test.

    FOVJAX_TEST_COMPILE_LOG=/tmp/compiles python -m pytest -q
    python tests/compile_report.py /tmp/compiles [--top 25]
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

KINDS = ("trace", "lower", "xla", "cache_read")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", type=Path)
    parser.add_argument("--top", type=int, default=25, help="rows per table (default 25)")
    args = parser.parse_args(argv)
    logs = sorted(args.directory.glob("compiles-*.jsonl"))
    if not logs:
        print(f"compile_report: no compiles-*.jsonl in {args.directory}", file=sys.stderr)
        return 2
    by_file = collections.defaultdict(lambda: collections.Counter())
    by_test = collections.defaultdict(lambda: collections.Counter())
    programs = collections.Counter()
    for log in logs:
        for n, line in enumerate(log.read_text().splitlines(), 1):
            try:
                row = json.loads(line)
                test, kind, seconds = row["test"], row["kind"], float(row["s"])
            except (ValueError, KeyError, TypeError) as err:
                print(f"compile_report: {log}:{n}: not a log line ({err})", file=sys.stderr)
                return 2
            by_file[test.split("::")[0]][kind] += seconds
            by_test[test][kind] += seconds
            if kind == "xla":
                by_file[test.split("::")[0]]["programs"] += 1
                programs[row.get("fun")] += 1
    total = collections.Counter()
    for counts in by_file.values():
        total.update(counts)
    print(
        f"{len(logs)} worker log(s); seconds: "
        + ", ".join(f"{k} {total[k]:.0f}" for k in KINDS)
        + f"; XLA compiles {int(total['programs'])}"
    )
    for title, table in (("by file", by_file), ("by test", by_test)):
        print(f"\n{title} (trace + lower + xla, s):")
        rows = sorted(table.items(), key=lambda kv: -(kv[1]["trace"] + kv[1]["lower"] + kv[1]["xla"]))
        for name, c in rows[: args.top]:
            spent = c["trace"] + c["lower"] + c["xla"]
            print(
                f"  {spent:7.1f}  xla {c['xla']:6.1f}  trace+lower {c['trace'] + c['lower']:6.1f}  "
                f"cache {c['cache_read']:5.1f}  {name}"
            )
    print("\nmost compiled functions (XLA compiles):")
    for fun, n in programs.most_common(args.top):
        print(f"  {n:4d}  {fun}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
