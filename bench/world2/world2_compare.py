#!/usr/bin/env python3
"""Compares partloc's result.json with world 2's truth.json for cells WORK/seed_N (N in the arguments).

Per scan: right (registered, within the scan's tolerance of the truth), WRONG (registered, outside it; or a
trap registered at all), rejected. Tolerance (truth.json, per scan): on 60 of the scan's fiducial points,
the largest distance between the point mapped by partloc's T_machine_scan and by the true one must be at
most 0.1 mm + |depth bias| + |scale error| x (the points' largest distance from the scanner's centre of scale,),
and the rotation between the two at most 0.05 deg. The bias and the scale error are the sensor's own
systematic errors: a right rigid fit of a biased or scaled scan is moved by them, and so is the part seen
in the same scan, so they do not harm the located part.
"""
import json, math, os, sys

MM = {"mm": 1.0, "um": 0.001, "m": 1000.0, "in": 25.4, "cm": 10.0}


def app(T, p):
    return [sum(T[i][j] * p[j] for j in range(3)) + T[i][3] for i in range(3)]


def inv(T):
    R = [[T[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(R[i][j] * T[j][3] for j in range(3)) for i in range(3)]
    return [R[0] + [t[0]], R[1] + [t[1]], R[2] + [t[2]], [0, 0, 0, 1]]


def mul(A, B):
    return [[sum(A[i][k] * B[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def rot_deg(A, B):  # angle of A.R * B.R^T
    tr = sum(A[i][k] * B[i][k] for i in range(3) for k in range(3))
    return math.degrees(math.acos(max(-1.0, min(1.0, (tr - 1) / 2))))


def euler(T):  # R = Rz(c) Ry(b) Rx(a)
    b = -math.asin(max(-1, min(1, T[2][0])))
    return [math.degrees(math.atan2(T[2][1], T[2][2])), math.degrees(b), math.degrees(math.atan2(T[1][0], T[0][0]))]


def wrap(d):
    return (d + 180) % 360 - 180


def main():
    work = sys.argv[1]
    seeds = sys.argv[2:]
    rows, wrongs, cells, details = [], [], [], []
    tot = {"right": 0, "WRONG": 0, "rejected": 0, "trap_rejected": 0, "trap_accepted": 0, "traps": 0,
           "n3000": 0, "right3000": 0, "wrong3000": 0, "scans": 0}
    for seed in seeds:
        d = os.path.join(work, "seed_" + seed)
        truth = json.load(open(os.path.join(d, "truth.json")))
        k = MM[truth["units"]]  # mm per job unit
        rp = os.path.join(d, "out", "result.json")
        res = json.load(open(rp)) if os.path.exists(rp) else None
        by_file = {s["file"]: s for s in (res["scans"] if res else [])}
        fids = {f["name"]: f["T_machine_fiducial"] for f in truth["fiducials"]}
        for ts in truth["scans"]:
            tot["scans"] += 1
            rs = by_file.get(ts["file"])
            trap = ts["trap"]
            fmax = max(ts["fiducial_points"].values()) if ts["fiducial_points"] else 0
            status = rs["status"] if rs else "no result"
            err = rot = None
            tol = ts["tolerance"]
            if rs and rs["status"] == "registered" and rs.get("T_machine_scan"):
                Te, Tt = rs["T_machine_scan"], ts["T_machine_scan"]
                # the scanner's scale as partloc fitted it: T (c + scale (p - c))
                sc, c0 = rs.get("scale") or 1.0, rs.get("scale_centre") or [0.0, 0.0, 0.0]
                err = max(math.dist(app(Te, [c0[i] + sc * (p[i] - c0[i]) for i in range(3)]), app(Tt, p))
                          for p in ts["check_points"])
                rot = rot_deg(Te, Tt)
                ok = err <= tol["translation"] and rot <= tol["rotation_deg"] and not trap
                cls = "right" if ok else "WRONG"
            else:
                cls = "rejected"
            if trap:
                tot["traps"] += 1
                tot["trap_rejected" if cls == "rejected" else "trap_accepted"] += 1
            tot[cls] += 1
            if not trap and fmax >= 3000:
                tot["n3000"] += 1
                tot["right3000"] += cls == "right"
                tot["wrong3000"] += cls == "WRONG"
            # for a rejected scan: how far each fiducial's best fit was from its true pose in the scan
            diag = ""
            if rs and cls == "rejected" and not trap:
                parts = []
                found = False
                for f in rs.get("fits", []):
                    if not f.get("T_scan_fiducial") or f["fiducial"] not in fids:
                        continue
                    # the fiducial where it was at the scan's A (truth gives it at A = 0; the rotary axis of
                    # world 2 turns about machine X through the origin and carries every body)
                    a = math.radians(ts.get("A", 0.0) if truth["rotary"] else 0.0)
                    MA = [[1, 0, 0, 0], [0, math.cos(a), -math.sin(a), 0], [0, math.sin(a), math.cos(a), 0], [0, 0, 0, 1]]
                    Ttrue = mul(inv(ts["T_machine_scan"]), mul(MA, fids[f["fiducial"]]))
                    Tf = f["T_scan_fiducial"]
                    # distance at the fiducial's origin
                    dt = math.dist([Tf[i][3] for i in range(3)], [Ttrue[i][3] for i in range(3)]) * k
                    parts.append("%s(%d pts) best fit %.2f mm %.2f deg off" % (
                        f["fiducial"], ts["fiducial_points"].get(f["fiducial"], 0), dt, rot_deg(Tf, Ttrue)))
                    if dt <= 1.0 and rot_deg(Tf, Ttrue) <= 0.2:
                        found = True
                diag = ("[found, refused] " if found else "[missed] ") + "; ".join(parts)
                if fmax >= 3000:
                    key = "rej3000_found" if found else "rej3000_missed"
                    tot[key] = tot.get(key, 0) + 1
            row = dict(seed=seed, file=ts["file"], trap=trap or "", fid=fmax, cls=cls,
                       err=None if err is None else err * k, rot=rot, tol=tol["translation"] * k,
                       msg=(rs or {}).get("message", "") if rs else "no result.json", diag=diag,
                       bias=ts["sensor"]["bias"] * k, scale=ts["sensor"]["scale_error"])
            if rs and rs.get("scale") not in (None, 1.0) and not trap:
                # the scale as fitted against the sensor's: p_scan = c + (1 + e) (p - c), so 1 / scale - 1 = e
                row["fitted_scale_error"] = 1.0 / rs["scale"] - 1.0
                row["scale_sigma"] = (rs.get("scale_sigma") or 0.0) / rs["scale"] ** 2
            rows.append(row)
            if cls == "WRONG":
                wrongs.append(row)
                if not trap and err <= 2 * tol["translation"] and rot <= 2 * tol["rotation_deg"]:
                    tot["wrong_within_2x"] = tot.get("wrong_within_2x", 0) + 1
        # the part
        cell = dict(seed=seed, layout=truth["layout"] + (" rotary" if truth["rotary"] else ""),
                    status=res["status"] if res else "no result", units=truth["units"])
        if res and res["status"] == "located" and res["workpiece"].get("T_machine_workpiece"):
            We, Wt = res["workpiece"]["T_machine_workpiece"], truth["T_machine_workpiece"]
            lo, hi = truth["workpiece_box"]
            corners = [[(lo, hi)[(c >> i) & 1][i] for i in range(3)] for c in range(8)]
            cell["corner_err"] = max(math.dist(app(We, app(inv(Wt), app(Wt, p))), app(Wt, p)) for p in corners) * k
            cell["corner_err"] = max(math.dist(app(We, p), app(Wt, p)) for p in corners) * k
            cell["origin_err"] = [(We[i][3] - Wt[i][3]) for i in range(3)]
            cell["rot_err"] = rot_deg(We, Wt)
            ee, et = euler(We), euler(Wt)
            cell["euler_err"] = [wrap(ee[i] - et[i]) for i in range(3)]
            u = res["workpiece"].get("uncertainty_95")
            if u:
                ratios = [abs(cell["origin_err"][i]) / max(u["origin"][i], 1e-300) for i in range(3)] + \
                         [abs(cell["euler_err"][i]) / max(u["euler_xyz_deg"][i], 1e-300) for i in range(3)]
                cell["ratio"] = max(ratios)
                cell["hw"] = u
            cell["origin_err"] = [x * k for x in cell["origin_err"]]
        cells.append(cell)

    print("=== WRONG answers (registered outside tolerance, or a trap registered) ===")
    if not wrongs:
        print("none")
    for r in wrongs:
        print("seed %s %s trap=%s fid_pts=%d err %.3f mm (tol %.3f) rot %.4f deg; bias %.3f scale %.5f" % (
            r["seed"], r["file"], r["trap"] or "-", r["fid"], r["err"], r["tol"], r["rot"], r["bias"], r["scale"]))
    bad_cells = [c for c in cells if c.get("corner_err") is not None and
                 (c["corner_err"] > 0.05 or c.get("ratio", 0) > 3)]
    print("=== located parts off by more than 0.05 mm or outside 3 of their half-widths ===")
    if not bad_cells:
        print("none")
    for c in bad_cells:
        print("seed %s: corner error %.3f mm, origin error [%s] mm, rotation %.4f deg, error/half-width %s" % (
            c["seed"], c["corner_err"], ", ".join("%.3f" % x for x in c["origin_err"]), c["rot_err"],
            "%.2f" % c["ratio"] if "ratio" in c else "n/a"))
    print()
    print("=== scans ===")
    print("%-5s %-17s %-11s %7s %-9s %8s %8s %7s  %s" % ("seed", "scan", "trap", "fidpts", "result", "err_mm",
                                                          "rot_deg", "tol_mm", "message / diagnosis"))
    for r in rows:
        print("%-5s %-17s %-11s %7d %-9s %8s %8s %7.3f  %s" % (
            r["seed"], r["file"], r["trap"] or "-", r["fid"], r["cls"],
            "-" if r["err"] is None else "%.3f" % r["err"], "-" if r["rot"] is None else "%.4f" % r["rot"],
            r["tol"], (r["diag"] or r["msg"])[:160]))
    print()
    fitted = [r for r in rows if "fitted_scale_error" in r]
    print("=== scanner scale fitted (scans registered on two fiducials or more) ===")
    print("%-5s %-17s %-9s %10s %10s %10s %9s" % ("seed", "scan", "result", "sensor", "fitted", "off", "sigma"))
    for r in fitted:
        print("%-5s %-17s %-9s %10.5f %10.5f %10.5f %9.2g" % (
            r["seed"], r["file"], r["cls"], r["scale"], r["fitted_scale_error"],
            r["fitted_scale_error"] - r["scale"], r["scale_sigma"]))
    if fitted:
        offs = sorted(abs(r["fitted_scale_error"] - r["scale"]) for r in fitted)
        raw = sorted(abs(r["scale"]) for r in fitted)
        print("fitted scale off the sensor's: median %.5f, max %.5f, over %d scans (the sensor's own: median %.5f, max %.5f)" % (
            offs[len(offs) // 2], offs[-1], len(offs), raw[len(raw) // 2], raw[-1]))
    print()
    print("=== cells ===")
    for c in cells:
        if c.get("corner_err") is not None:
            hw = c.get("hw")
            print("seed %-4s %-14s %-11s corner err %.4f mm  origin err [%s]  rot %.4f deg  hw95 origin [%s] euler [%s]  err/hw %s" % (
                c["seed"], c["layout"], c["status"], c["corner_err"], ", ".join("%.4f" % x for x in c["origin_err"]),
                c["rot_err"], ", ".join("%.4f" % (x * MM[c["units"]]) for x in hw["origin"]) if hw else "-",
                ", ".join("%.4f" % x for x in hw["euler_xyz_deg"]) if hw else "-",
                "%.2f" % c["ratio"] if "ratio" in c else "n/a"))
        else:
            print("seed %-4s %-14s %s" % (c["seed"], c["layout"], c["status"]))
    print()
    nonTrap = tot["scans"] - tot["traps"]
    located = [c for c in cells if c.get("corner_err") is not None]
    print("=== totals over %d cells (seeds %s..%s), %d scans ===" % (len(cells), seeds[0], seeds[-1], tot["scans"]))
    print("scans (not traps): %d: right %d, WRONG %d, rejected %d" % (
        nonTrap, tot["right"], tot["WRONG"] - tot["trap_accepted"], tot["rejected"] - tot["trap_rejected"]))
    print("  of the WRONG ones, within twice the tolerance: %d" % tot.get("wrong_within_2x", 0))
    print("recall on scans with >= 3000 points of a fiducial: %d of %d right (%.1f %%), %d WRONG" % (
        tot["right3000"], tot["n3000"], 100.0 * tot["right3000"] / max(1, tot["n3000"]), tot["wrong3000"]))
    print("  of the rejected ones: a fiducial's best fit within 1 mm and 0.2 deg of its true pose (found, refused by a check): %d;"
          " no best fit near it (missed by the search): %d" % (tot.get("rej3000_found", 0), tot.get("rej3000_missed", 0)))
    print("traps: %d, rejected %d, registered %d" % (tot["traps"], tot["trap_rejected"], tot["trap_accepted"]))
    print("cells located: %d of %d" % (len(located), len(cells)))
    if located:
        ce = sorted(c["corner_err"] for c in located)
        print("located part error at its box corners: median %.4f mm, max %.4f mm; within 0.05 mm: %d of %d" % (
            ce[len(ce) // 2], ce[-1], sum(1 for x in ce if x <= 0.05), len(ce)))
        rr = [c["ratio"] for c in located if "ratio" in c]
        if rr:
            print("error / reported 95%% half-width (largest of 6 components): median %.2f, max %.2f; within 3: %d of %d (%d without half-widths)" % (
                sorted(rr)[len(rr) // 2], max(rr), sum(1 for x in rr if x <= 3), len(rr), len(located) - len(rr)))


if __name__ == "__main__":
    main()
