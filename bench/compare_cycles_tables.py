#!/usr/bin/env python3
"""Compares `brdfkit albedo --preset cycles --json` with Blender Cycles'
shipped src/scene/shader.tables, table by table: the largest and mean
absolute difference, where the largest sits (x, y, z indices, x fastest),
and how many entries differ by more than 1e-3.

    build/brdfkit albedo --preset cycles --json > cycles.json
    /usr/bin/python3 bench/compare_cycles_tables.py cycles.json path/to/shader.tables
"""
import json
import re
import sys


def shipped_arrays(path):
    text = open(path, encoding="utf-8").read()
    arrays = {}
    for m in re.finditer(r"static const float (\w+)\[(\d+)\]\s*=\s*\{(.*?)\};", text, re.S):
        values = [float(v.rstrip("f")) for v in re.findall(r"[-+0-9.eE]+f?", m.group(3))]
        if len(values) != int(m.group(2)):
            sys.exit(f"{path}: {m.group(1)} has {len(values)} values, declared {m.group(2)}")
        arrays[m.group(1)] = values
    return arrays


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    ours = json.load(open(sys.argv[1], encoding="utf-8"))
    shipped = shipped_arrays(sys.argv[2])
    print(f"{'table':32s} {'entries':>7s} {'max |diff|':>11s} {'at (x,y,z)':>12s} {'ours':>9s} {'shipped':>9s} "
          f"{'mean |diff|':>11s} {'> 1e-3':>7s}")
    for t in ours["tables"]:
        name, values = t["name"], t["value"]
        if name not in shipped:
            print(f"{name:32s} not in {sys.argv[2]}")
            continue
        s = shipped[name]
        if len(s) != len(values):
            sys.exit(f"{name}: {len(values)} entries here, {len(s)} shipped")
        diffs = [abs(a - b) for a, b in zip(values, s)]
        k = max(range(len(diffs)), key=diffs.__getitem__)
        dims = [len(a["nodes"]) for a in t["axes"]]
        idx, rest = [], k
        for n in dims:
            idx.append(rest % n)
            rest //= n
        at = "(" + ",".join(str(i) for i in idx) + ")"
        print(f"{name:32s} {len(values):7d} {diffs[k]:11.2e} {at:>12s} {values[k]:9.6f} {s[k]:9.6f} "
              f"{sum(diffs) / len(diffs):11.2e} {sum(d > 1e-3 for d in diffs):7d}")


if __name__ == "__main__":
    main()
