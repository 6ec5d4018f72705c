#!/usr/bin/env python3
"""Coverage of the 95 % intervals under different ways of combining the uncertainty's parts.

Reads the output of `build/bench/partloc_trials` (a trial line, then its `sigma` line with the 1-sigma parts
from the scans (jackknife), the probing and the noise, and the jackknife's scan count) and prints, for each
rule, how often the truth lies inside [located - u, located + u] per component, and the RMS of error / sigma
(1 for an honest sigma).

    python3 bench/trials/coverage.py bench/results/trials_XXXX.txt [more files]
"""
import math
import sys

T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228]


def t95(dof):
    return T95[max(1, min(dof, len(T95))) - 1] if dof <= len(T95) else 1.96 + 2.4 / dof


def read(paths):
    trials = []
    for path in paths:
        last = None
        for line in open(path):
            p = line.split()
            if len(p) == 14 and p[0].isdigit():
                v = [float(x) for x in p[1:13]]
                last = {"seed": int(p[0]), "err": v[0:3] + v[6:9], "u": v[3:6] + v[9:12]}
            elif p[:2] == ["sigma", "scans"] and last is not None:
                last["scans"] = [float(x) for x in p[2:8]]
                last["probing"] = [float(x) for x in p[9:15]]
                last["noise"] = [float(x) for x in p[16:22]]
                last["m"] = int(p[23])
                # From 2000-2099's rerun on: the part of the jackknife's scatter that the probing explains.
                at = p.index("probing_in_scans") if "probing_in_scans" in p else -1
                last["pis"] = [float(x) for x in p[at + 1:at + 7]] if at >= 0 else None
                trials.append(last)
                last = None
    return trials


RULES = {
    # The rule in pipeline/uncertainty.cpp up to bddd94c.
    "t(m-1)*scans + 1.96*(probing + noise)": lambda t, a: math.sqrt(
        (t95(t["m"] - 1) * t["scans"][a]) ** 2 + (1.96 * t["probing"][a]) ** 2 + (1.96 * t["noise"][a]) ** 2),
    "1.96*(scans + probing + noise)": lambda t, a: 1.96 * math.sqrt(
        t["scans"][a] ** 2 + t["probing"][a] ** 2 + t["noise"][a] ** 2),
    # The rule in pipeline/uncertainty.cpp from 0ded79d (after the fresh seeds 1200-1299) to 17d0f91.
    "1.96*(scans + probing)": lambda t, a: 1.96 * math.sqrt(t["scans"][a] ** 2 + t["probing"][a] ** 2),
    # The rule in pipeline/uncertainty.cpp after 17d0f91 (picked on seeds 1800-1899, checked on 1900-1999).
    "1.96*(max(scans, noise) + probing)": lambda t, a: 1.96 * math.sqrt(
        max(t["scans"][a], t["noise"][a]) ** 2 + t["probing"][a] ** 2),
    # The jackknife less the probing's share of its scatter, the noise as a floor, then the probing.
    "1.96*(max(scans - pis, noise) + probing)": lambda t, a: 1.96 * math.sqrt(
        max(t["scans"][a] ** 2 - t["pis"][a] ** 2, t["noise"][a] ** 2) + t["probing"][a] ** 2)
    if t["pis"] else float("nan"),
    "t(m-1)*(scans + probing)": lambda t, a: t95(t["m"] - 1) * math.sqrt(t["scans"][a] ** 2 + t["probing"][a] ** 2),
    # The rule in pipeline/uncertainty.cpp from f7b39b1 to 0ded79d.
    "1.96*max(scans, noise + probing)": lambda t, a: 1.96 * max(
        t["scans"][a], math.hypot(t["noise"][a], t["probing"][a])),
    "t(m-1)*max(scans, noise) + 1.96*probing": lambda t, a: math.sqrt(
        (t95(t["m"] - 1) * max(t["scans"][a], t["noise"][a])) ** 2 + (1.96 * t["probing"][a]) ** 2),
}

NAMES = ["x", "y", "z", "a", "b", "c"]


def main():
    trials = read(sys.argv[1:])
    n = len(trials)
    print(f"{n} trials with the parts of their uncertainty")
    if not n:
        return
    print("RMS over the trials, 1 sigma:   " + " ".join(f"{c:>7}" for c in NAMES))
    for name, key in [("measured error", "err"), ("scans (jackknife)", "scans"), ("probing", "probing"),
                      ("noise (information)", "noise")]:
        rms = [math.sqrt(sum(t[key][a] ** 2 for t in trials) / n) for a in range(6)]
        print(f"  {name:<29}" + " ".join(f"{r:7.4f}" for r in rms))
    have = [t for t in trials if t.get("pis")]
    if have:
        rms = [math.sqrt(sum(t["pis"][a] ** 2 for t in have) / len(have)) for a in range(6)]
        print(f"  {'probing in the jackknife':<29}" + " ".join(f"{r:7.4f}" for r in rms))
    # What the points' noise and the fiducials' probing allow together: the bound the error can reach.
    rms = [math.sqrt(sum(t["noise"][a] ** 2 + t["probing"][a] ** 2 for t in trials) / n) for a in range(6)]
    print(f"  {'bound: noise and probing':<29}" + " ".join(f"{r:7.4f}" for r in rms))
    print("coverage % per component, then RMS of error/sigma (sigma = u/1.96):")
    for name, rule in RULES.items():
        inside = [sum(abs(t["err"][a]) <= rule(t, a) for t in trials) / n * 100 for a in range(6)]
        z = [math.sqrt(sum((t["err"][a] / (rule(t, a) / 1.96)) ** 2 for t in trials) / n) for a in range(6)]
        print(f"  {name:<38}" + " ".join(f"{c:5.1f}" for c in inside) + "   z " + " ".join(f"{v:4.2f}" for v in z))


if __name__ == "__main__":
    main()
