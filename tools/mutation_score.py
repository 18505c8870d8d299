"""Mutation score per mutated file from mutmut 2's cache: killed / (killed + survived + timed out).

Usage: ``python tools/mutation_score.py .mutmut-cache`` (read a copy while mutmut runs: a locked cache stops it).
"Suspicious" mutants (killed, but slowly) count as killed; untested ones are listed and not scored.
"""

from __future__ import annotations

import collections
import sqlite3
import sys

KILLED = ("ok_killed", "ok_suspicious")
ALIVE = ("bad_survived", "bad_timeout")


def counts(cache: str) -> dict[str, collections.Counter[str]]:
    """File -> status -> number of mutants."""
    db = sqlite3.connect(cache)
    rows = db.execute("select s.filename, m.status, count(*) from Mutant m join Line l on m.line = l.id "
                      "join SourceFile s on l.sourcefile = s.id group by s.filename, m.status").fetchall()
    by_file: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for filename, status, n in rows:
        by_file[filename][status] += n
    return by_file


def line(name: str, c: collections.Counter[str]) -> str:
    killed, alive = sum(c[s] for s in KILLED), sum(c[s] for s in ALIVE)
    return (f"{name:42s} killed {killed:4d}  survived {c['bad_survived']:4d}  timeout {c['bad_timeout']:3d}  "
            f"untested {c['untested']:3d}  score {killed / max(killed + alive, 1):.1%}")


def main() -> None:
    by_file = counts(sys.argv[1])
    total: collections.Counter[str] = collections.Counter()
    for filename in sorted(by_file):
        print(line(filename, by_file[filename]))
        total.update(by_file[filename])
    print(line("TOTAL", total))


if __name__ == "__main__":
    main()
