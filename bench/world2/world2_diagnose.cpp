// partloc_world2_diagnose CELL...: where the global search loses a fiducial's true pose (issue 25, item 2).
// For every scan of a world-2 cell (CELL/job.yaml and CELL/truth.json, as world2_trials.sh --keep leaves
// them) and every fiducial the truth says it sees with at least --min-points points, one line:
//   ppf      the rank (0 = most votes) of the first global-fit candidate within --near-deg and
//            --near-samplings (at the model's centre) of the true pose, or "-" when none is;
//   truth    the fine fit and verification started at the true pose: "ok" or its reason, i.e. whether the
//            checks can accept the true pose at all;
//   fits     the fine-fitted candidates (fit_candidates): "right" (a valid one within 0.5 mm and 0.5 deg of
//            the truth), "wrong" (a valid one away from it comes first) or the best one's reason.
// Unlike the generator, this tool links partloc: it asks the library's steps one at a time.
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/icp.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/core/median.hpp"
#include "partloc/core/ppf.hpp"
#include "partloc/core/verify.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/pipeline/config.hpp"
#include "partloc/pipeline/run.hpp"

namespace {

Eigen::Isometry3d matrix_of(const nlohmann::json& j) {
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(r, c) = j.at(r).at(c).get<double>();
    Eigen::Isometry3d T;
    T.matrix() = m;
    return T;
}

struct Offset {
    double at_centre = 0.0;  ///< distance of the model's centre under the two poses (job units)
    double deg = 0.0;
};

Offset offset(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, const Eigen::Vector3d& centre) {
    const Eigen::AngleAxisd d(a.linear() * b.linear().transpose());
    return {(a * centre - b * centre).norm(), d.angle() * 180.0 / M_PI};
}

/// Signed residuals of the points (scan frame) near the model at T_model_scan, within `window` of the
/// nearest of their four nearest samples' planes: their median and robust sigma (1.4826 MAD about it).
struct Residuals {
    std::size_t n = 0;
    double median = 0.0, sigma = 0.0;
};
Residuals residuals_at(const std::vector<Eigen::Vector3d>& pts, const partloc::Surface& model,
                       const Eigen::Isometry3d& T_model_scan, double window) {
    std::vector<double> r;
    for (const auto& p0 : pts) {
        const Eigen::Vector3d p = T_model_scan * p0;
        int nn[4];
        double d2[4];
        const int found = model.nearest(p, 4, window + model.spacing, nn, d2);
        double ri = 0.0;
        if (partloc::nearest_plane(model, p, nullptr, 0.0, nn, found, &ri) < 0 || std::abs(ri) > window)
            continue;
        r.push_back(ri);
    }
    Residuals out;
    out.n = r.size();
    out.median = partloc::median_of(r);
    for (double& x : r) x = std::abs(x - out.median);
    out.sigma = 1.4826 * partloc::median_of(r);
    return out;
}

std::string short_reason(const std::string& r) { return r.substr(0, std::min<std::size_t>(r.size(), 60)); }

}  // namespace

int main(int argc, char** argv) {
    using namespace partloc;
    std::size_t min_points = 3000;
    bool verbose = false, residuals = false;
    std::string dump;
    int max_candidates = 0, stride = 0, per_location = 0;  // 0: the model's own PPF settings
    double near_deg = 15.0, near_samplings = 3.0;
    std::vector<std::string> cells;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--max-candidates" && i + 1 < argc)
            max_candidates = std::stoi(argv[++i]);
        else if (a == "--per-location" && i + 1 < argc)
            per_location = std::stoi(argv[++i]);
        else if (a == "--stride" && i + 1 < argc)
            stride = std::stoi(argv[++i]);
        else if (a == "--dump" && i + 1 < argc)
            dump = argv[++i];
        else if (a == "--verbose")
            verbose = true;
        else if (a == "--residuals")
            residuals = true;
        else if (a == "--min-points" && i + 1 < argc)
            min_points = std::stoul(argv[++i]);
        else if (a == "--near-deg" && i + 1 < argc)
            near_deg = std::stod(argv[++i]);
        else if (a == "--near-samplings" && i + 1 < argc)
            near_samplings = std::stod(argv[++i]);
        else
            cells.push_back(a);
    }
    if (cells.empty()) {
        std::fprintf(stderr,
                     "usage: partloc_world2_diagnose [--min-points N] [--near-deg D] "
                     "[--near-samplings S] CELL...\n");
        return 2;
    }
    std::printf("%-30s %-4s %6s %5s %9s  %-34s %s\n", "cell scan", "fid", "points", "ppf", "votes", "truth",
                "fits");
    for (const auto& cell : cells) {
        const std::filesystem::path dir(cell);
        const Job job = io::load_job(dir / "job.yaml");
        nlohmann::json truth;
        std::ifstream(dir / "truth.json") >> truth;
        RunSettings rs;
        const JobPreparation prep = prepare_job(job, rs);
        const LocalizeSettings& st = rs.config.candidates;
        for (std::size_t i = 0; i < job.scans.size(); ++i) {
            const Scan& scan = job.scans[i];
            const nlohmann::json* ts = nullptr;
            for (const auto& t : truth.at("scans"))
                if (t.at("file").get<std::string>() == scan.file) ts = &t;
            if (!ts || !(*ts).at("trap").is_null()) continue;
            const Eigen::Isometry3d T_machine_scan = matrix_of(ts->at("T_machine_scan"));
            const Scale& scale = prep.scales[i];
            const Eigen::Vector3d viewpoint = estimate_viewpoint(*scan.points, scale.spacing);
            const PreparedScan ps = prepare_scan(*scan.points, scale, prep.sampling, viewpoint);
            for (std::size_t k = 0; k < job.fiducials.size(); ++k) {
                const auto& f = job.fiducials[k];
                const auto& fp = ts->at("fiducial_points");
                const std::size_t n = fp.contains(f.name) ? fp.at(f.name).get<std::size_t>() : 0;
                if (n < min_points) continue;
                const PreparedModel& m = prep.models[k];
                const Eigen::Isometry3d T_true =
                    T_machine_scan.inverse() * fiducial_at(job.machine, f, scan.axes);
                // The global fit as the run makes it, or with other settings (--max-candidates, --stride).
                std::vector<PoseCandidate> cands;
                if (max_candidates > 0 || stride > 0 || per_location > 0) {
                    PpfSettings s2 = m.ppf->settings();
                    if (max_candidates > 0) s2.max_candidates = max_candidates;
                    if (stride > 0) s2.reference_stride = stride;
                    if (per_location > 0) s2.per_location = per_location;
                    const PpfModel other(m.ppf->points(), m.ppf->normals(), s2);
                    cands = ppf_detect(other, ps.coarse_points, ps.coarse_normals);
                } else {
                    cands = ppf_detect(*m.ppf, ps.coarse_points, ps.coarse_normals);
                }
                int rank = -1;
                for (std::size_t c = 0; c < cands.size() && rank < 0; ++c) {
                    const Offset o = offset(cands[c].T_scene_model, T_true, m.dense.center);
                    if (o.deg < near_deg && o.at_centre < near_samplings * m.sampling)
                        rank = static_cast<int>(c);
                }
                // The scan's points around the fiducial where T (scan <- model) puts it.
                const auto points_around = [&](const Eigen::Isometry3d& T) {
                    std::vector<int> near_idx;
                    ps.grid->within(T * m.dense.center, m.dense.diameter / 2.0 + 2.0 * m.sampling, near_idx);
                    std::vector<Eigen::Vector3d> out;
                    for (int j : near_idx) out.push_back(ps.cloud->points_[j]);
                    return out;
                };
                // The fine-fitted candidates, as the run makes them (fit_candidates).
                const auto fits = fit_candidates(ps, m, st, cands);
                if (verbose) {
                    // The verification at the true pose itself, bin by bin, with the run's tolerances.
                    const VerifySettings vs = verify_settings(ps, m);
                    std::vector<int> idx;
                    const std::vector<Eigen::Vector3d> local = points_around(T_true);
                    const Verification v = verify_pose(local, m.dense, T_true.inverse(), ps.viewpoint, vs);
                    if (!dump.empty()) {
                        // The points near the fiducial and its samples, model frame, for a look by eye.
                        std::ofstream o(dump + "_" + dir.filename().string() + "_" + std::to_string(i) + "_" +
                                        f.name + ".xyz");
                        for (const auto& q : local) {
                            const Eigen::Vector3d p = T_true.inverse() * q;
                            o << p.x() << ' ' << p.y() << ' ' << p.z() << " 0\n";
                        }
                        for (const auto& q : m.dense.points)
                            o << q.x() << ' ' << q.y() << ' ' << q.z() << " 1\n";
                        const Eigen::Vector3d e = T_true.inverse() * ps.viewpoint;
                        o << e.x() << ' ' << e.y() << ' ' << e.z() << " 2\n";
                    }
                    std::printf(
                        "  at truth: inliers %zu rmse %.3f observed %zu seen_through %zu crowded %zu "
                        "occluded %zu missing %zu overflow %zu; noise %.3f inlier distance %.3f "
                        "viewpoint %.1f %.1f %.1f\n",
                        v.inliers, v.rmse, v.observed, v.seen_through, v.crowded, v.occluded, v.missing,
                        v.overflow, scale.noise, vs.inlier_distance, ps.viewpoint.x(), ps.viewpoint.y(),
                        ps.viewpoint.z());
                    // The screening's coarse fit from the true pose, with fit_candidates' stages (copied:
                    // they are local to it).
                    IcpSettings coarse;
                    coarse.max_distances = {2.0 * m.sampling, 1.0 * m.sampling};
                    coarse.max_iterations = 10;
                    coarse.approximate_from = m.sampling;
                    idx.clear();
                    ps.sparse_grid->within(T_true * m.dense.center, m.dense.diameter / 2.0 + 2.0 * m.sampling,
                                           idx);
                    std::vector<Eigen::Vector3d> sub;
                    const std::size_t every =
                        std::max<std::size_t>(1, (idx.size() + st.screen_points - 1) / st.screen_points);
                    for (std::size_t j = 0; j < idx.size(); j += every)
                        sub.push_back(ps.sparse->points_[static_cast<std::size_t>(idx[j])]);
                    for (int stages = 1; stages <= 2; ++stages) {
                        IcpSettings c = coarse;
                        c.max_distances.resize(stages);
                        const IcpResult r = icp_point_to_plane(sub, m.dense, T_true.inverse(), c);
                        const Offset o = offset(r.T_target_source.inverse(), T_true, m.dense.center);
                        std::printf("  coarse from truth, %d stage(s): %.2f mm %.2f deg\n", stages,
                                    o.at_centre, o.deg);
                    }
                    IcpSettings fine;
                    fine.max_distances = {0.5 * m.sampling, 0.25 * m.sampling};
                    fine.max_iterations = 15;
                    const IcpResult r = icp_point_to_plane(sub, m.dense, T_true.inverse(), fine);
                    const Offset o = offset(r.T_target_source.inverse(), T_true, m.dense.center);
                    std::printf("  fine from truth: %.2f mm %.2f deg\n", o.at_centre, o.deg);
                }
                if (residuals) {
                    // The sensor's error about the model where a right rigid fit puts it (the reference fit;
                    // the truth where there is none), and where the run's best candidate is: the residuals'
                    // median and robust sigma within 0.2 and 0.5 samplings, beside the noise partloc assumes,
                    // and the verification's violation with that noise and with the residuals' sigma.
                    Eigen::Isometry3d T_ref = T_true;
                    if (ts->contains("T_machine_scan_reference_fit"))
                        T_ref = matrix_of(ts->at("T_machine_scan_reference_fit")).inverse() *
                                fiducial_at(job.machine, f, scan.axes);
                    const std::vector<Eigen::Vector3d> local = points_around(T_ref);
                    const auto show = [&](const char* what, const Eigen::Isometry3d& T_sm) {
                        const Residuals a = residuals_at(local, m.dense, T_sm.inverse(), 0.2 * m.sampling);
                        const Residuals b = residuals_at(local, m.dense, T_sm.inverse(), 0.5 * m.sampling);
                        VerifySettings vs = verify_settings(ps, m);
                        const Verification v0 = verify_pose(local, m.dense, T_sm.inverse(), ps.viewpoint, vs);
                        const double se = std::max(scale.noise, a.sigma);
                        vs.inlier_distance =
                            std::abs(a.median) +
                            std::sqrt(9.0 * se * se + 0.5 * m.dense.spacing * m.dense.spacing);
                        const Verification v1 = verify_pose(local, m.dense, T_sm.inverse(), ps.viewpoint, vs);
                        const Offset o = offset(T_sm, T_true, m.dense.center);
                        std::printf(
                            "  residuals %s (%.2f mm %.2f deg from truth): noise %.3f s %.2f | 0.2s: n %zu "
                            "med %+.3f sig %.3f | 0.5s: n %zu med %+.3f sig %.3f | viol %.3f -> %.3f "
                            "overflow %zu -> %zu\n",
                            what, o.at_centre, o.deg, scale.noise, m.sampling, a.n, a.median, a.sigma, b.n,
                            b.median, b.sigma, v0.violation, v1.violation, v0.overflow, v1.overflow);
                    };
                    show("reference", T_ref);
                    if (!fits.empty())
                        show(fits.front().valid ? "best(valid)" : "best(refused)",
                             fits.front().T_scan_fiducial);
                }
                const auto at_truth = fit_candidates(ps, m, st, {PoseCandidate{T_true, 1.0}});
                std::string truth_says = at_truth.empty() ? "no fit" : at_truth.front().valid ? "ok" : "";
                if (!at_truth.empty() && !at_truth.front().valid)
                    truth_says = short_reason(at_truth.front().reason);
                std::string fits_say = "none";
                if (!fits.empty()) {
                    const FiducialFit& best = fits.front();
                    const Offset o = offset(best.T_scan_fiducial, T_true, m.dense.center);
                    const bool near = o.at_centre < 0.5 && o.deg < 0.5;
                    char buf[200];
                    if (best.valid)
                        std::snprintf(buf, sizeof buf, "%s (%.2f, %.2f deg) weak bins %zu/%zu",
                                      near ? "right" : "wrong", o.at_centre, o.deg, best.weakest_observed,
                                      best.weakest_against);
                    else
                        std::snprintf(buf, sizeof buf, "%s (%.1f, %.1f deg): %s", near ? "near" : "far",
                                      o.at_centre, o.deg, short_reason(best.reason).c_str());
                    fits_say = buf;
                }
                if (verbose && !at_truth.empty() && !fits.empty()) {
                    // Where the fit from the truth ends and how much of the scan it explains, beside the
                    // run's first fit: a first fit with less support than the truth's is a local optimum.
                    const FiducialFit& a = at_truth.front();
                    const FiducialFit& b = fits.front();
                    const Offset oa = offset(a.T_scan_fiducial, T_true, m.dense.center);
                    const Offset ob = offset(b.T_scan_fiducial, a.T_scan_fiducial, m.dense.center);
                    std::printf(
                        "  from truth: %s %.3f mm %.3f deg, support %.1f (inliers %zu score %.4f "
                        "cond %.4f weak bins %zu/%zu); run's first: support %.1f "
                        "(inliers %zu score %.4f cond %.4f weak bins %zu/%zu), "
                        "%.3f mm %.3f deg from it\n",
                        a.valid ? "valid" : "invalid", oa.at_centre, oa.deg, support(a), a.inliers, a.score,
                        a.conditioning, a.weakest_observed, a.weakest_against, support(b), b.inliers, b.score,
                        b.conditioning, b.weakest_observed, b.weakest_against, ob.at_centre, ob.deg);
                    // Which faces pull the fit from the truth towards where it ends: at the truth, each
                    // point's Tukey-weighted residual times its sample normal's share of the slide direction,
                    // summed by the sample's normal (rounded to 0.1).
                    const Eigen::Isometry3d D = T_true.inverse() * a.T_scan_fiducial;  // model -> model
                    const Eigen::Vector3d v = D * m.dense.center - m.dense.center;
                    if (v.norm() > 0.1 * m.sampling) {
                        const Eigen::Vector3d vh = v.normalized();
                        const double c = verify_settings(ps, m).inlier_distance;
                        std::vector<int> idx2;
                        ps.grid->within(T_true * m.dense.center, m.dense.diameter / 2.0 + 2.0 * m.sampling,
                                        idx2);
                        std::map<std::string, std::pair<double, int>> pull;
                        for (int j : idx2) {
                            const Eigen::Vector3d q = T_true.inverse() * ps.cloud->points_[j];
                            int nn[8];
                            double d2[8];
                            const int found = m.dense.nearest(q, 4, c, nn, d2);
                            double r = 0.0;
                            const int k2 = nearest_plane(m.dense, q, nullptr, 0.0, nn, found, &r);
                            if (k2 < 0 || std::abs(r) >= c) continue;
                            const Eigen::Vector3d& n = m.dense.normals[k2];
                            char key[80];
                            std::snprintf(key, sizeof key, "n(%+.1f %+.1f %+.1f) at(%+.0f %+.0f %+.0f)",
                                          n.x() + 0.0, n.y() + 0.0, n.z() + 0.0,
                                          std::round(m.dense.points[k2].x() / 10) * 10,
                                          std::round(m.dense.points[k2].y() / 10) * 10,
                                          std::round(m.dense.points[k2].z() / 10) * 10);
                            auto& e = pull[key];
                            e.first += tukey_weight(r, c) * r * n.dot(vh);
                            e.second += 1;
                        }
                        std::printf(
                            "  slide (model frame) %.3f %.3f %.3f; pulls by face (sum w r n.v, points):\n",
                            v.x(), v.y(), v.z());
                        std::vector<std::pair<double, std::string>> order;
                        for (const auto& [k3, e] : pull) order.push_back({-std::abs(e.first), k3});
                        std::sort(order.begin(), order.end());
                        for (std::size_t o2 = 0; o2 < order.size() && o2 < 12; ++o2)
                            std::printf("    %-40s %+9.3f %6d\n", order[o2].second.c_str(),
                                        pull[order[o2].second].first, pull[order[o2].second].second);
                    }
                }
                std::printf(
                    "%-30s %-4s %6zu %5s %4.0f/%4.0f  %-34s %s\n",
                    (dir.filename().string() + " " + std::filesystem::path(scan.file).filename().string())
                        .c_str(),
                    f.name.c_str(), n, rank < 0 ? "-" : std::to_string(rank).c_str(),
                    rank < 0 ? 0.0 : cands[static_cast<std::size_t>(rank)].votes,
                    cands.empty() ? 0.0 : cands.front().votes, truth_says.substr(0, 34).c_str(),
                    fits_say.c_str());
                std::fflush(stdout);
            }
        }
    }
    return 0;
}
