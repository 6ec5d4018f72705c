#include "partloc/core/workpiece_fit.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>

#include "partloc/core/icp.hpp"

namespace partloc {

WorkpieceFit fit_reference_surfaces(const std::vector<Eigen::Vector3d>& merged, const Surface& reference,
                                    const WorkpieceFitSettings& st,
                                    const std::vector<Eigen::Vector3d>* normals) {
    if (normals && normals->size() != merged.size()) normals = nullptr;
    WorkpieceFit fit;
    if (merged.size() < st.min_inliers) {
        fit.reason =
            "too few workpiece points (" + std::to_string(merged.size()) + ") to fit the reference surfaces";
        return fit;
    }
    // The last stage keeps only points within three noise sigmas (plus the model's sampling) of the surfaces.
    const double D = reference.diameter;
    const double start = st.max_start_distance > 0 ? st.max_start_distance : 0.1 * D;
    const double fine = std::sqrt(9.0 * st.noise * st.noise + 0.25 * reference.spacing * reference.spacing);
    // The coarse stages need only ten thousand points; the last uses up to 60,000 (the noise's share of the
    // error then is far below its bias share: about 0.13 / sqrt(60000) mm per direction).
    std::vector<Eigen::Vector3d> sub, last, last_n;
    const std::size_t stride = std::max<std::size_t>(1, merged.size() / 10000);
    for (std::size_t i = 0; i < merged.size(); i += stride) sub.push_back(merged[i]);
    const std::size_t stride_last = std::max<std::size_t>(1, merged.size() / 60000);
    for (std::size_t i = 0; i < merged.size(); i += stride_last) {
        last.push_back(merged[i]);
        if (normals) last_n.push_back((*normals)[i]);
    }
    // Coarse to fine from nominal, from several first distances: the part sits millimetres and degrees off
    // nominal, and the widest stage also takes in points of faces that are not reference surfaces, near
    // them, which can hold the fit in a wrong place that the narrower stages then keep (measured: seed
    // 1150, the part 1.6 degrees off; from 0.1 of the size the fit ended 20.5 degrees off, even when it
    // started at the truth, with 4386 points on the surfaces against 16794 at the truth). Each schedule
    // halves its distance down to four times the last stage's; the fit with the most points on the
    // surfaces in the last stage wins. The coarse stages take no normals: millimetres and degrees off,
    // they would refuse right correspondences.
    std::vector<double> firsts;
    for (double d = start; d > 4.0 * fine; d *= 0.5) firsts.push_back(d);
    firsts.push_back(4.0 * fine);
    IcpResult icp, first, coarse_prev;
    for (std::size_t k = 0; k < firsts.size(); ++k) {
        IcpSettings coarse;
        coarse.max_distances.assign(firsts.begin() + static_cast<std::ptrdiff_t>(k), firsts.end());
        coarse.max_iterations = 25;
        const IcpResult f = icp_point_to_plane(sub, reference, Eigen::Isometry3d::Identity(), coarse);
        // A schedule that ends where the previous one did would end the same.
        if (k > 0) {
            const Eigen::Isometry3d d = f.T_target_source * coarse_prev.T_target_source.inverse();
            if (Eigen::AngleAxisd(d.linear()).angle() * D + d.translation().norm() < 0.1 * fine) continue;
        }
        coarse_prev = f;
        const IcpResult g =
            fit_last_stage(last, reference, f.T_target_source, fine, normals ? &last_n : nullptr);
        if (k == 0 || g.inliers > icp.inliers) {
            icp = g;
            first = f;
        }
    }
    icp.iterations += first.iterations;
    fit.iterations = icp.iterations;
    fit.distance = fine;
    fit.T_located_nominal = icp.T_target_source.inverse();
    fit.rmse = icp.rmse;
    fit.inliers = icp.inliers;
    fit.JtJ = icp.JtJ;
    // Conditioning as in verify_pose: rotations scaled by half the diameter about the centre.
    if (icp.inliers) {
        const Matrix6d S = centred_scaled(reference.center, std::max(D / 2.0, 1e-12));
        const Matrix6d N = S * icp.JtJ * S.transpose() / static_cast<double>(icp.inliers);
        Eigen::SelfAdjointEigenSolver<Matrix6d> es(N);
        fit.conditioning = std::max(0.0, es.eigenvalues()(0));
    }
    char buf[400];
    if (icp.inliers < st.min_inliers) {
        std::snprintf(buf, sizeof buf, "only %zu points lie on the reference surfaces (needs %zu)",
                      icp.inliers, st.min_inliers);
        fit.reason = buf;
    } else if (fit.conditioning < st.min_conditioning) {
        std::snprintf(buf, sizeof buf,
                      "the scans do not show enough of the reference surfaces to fix all six degrees of "
                      "freedom (conditioning %.4f, needs %.3f)",
                      fit.conditioning, st.min_conditioning);
        fit.reason = buf;
    } else if (st.noise > 0 && fit.rmse > st.max_rmse_noise * st.noise) {
        // A coarse fit that slid into the wrong place keeps only the points that happen to lie near the
        // surfaces there, scattered over the whole band (measured: seed 1150, 19.5 degrees off, RMS 0.19 mm
        // against 0.08-0.10 for the right fits of 162 trials, scanner noise 0.13 mm).
        std::snprintf(
            buf, sizeof buf,
            "the points on the reference surfaces scatter %.3g about them (RMS), more than %.3g times "
            "the noise (%.3g): the fit did not find the part (it may sit further from nominal than "
            "the fit reaches)",
            fit.rmse, st.max_rmse_noise, st.noise);
        fit.reason = buf;
    } else {
        fit.valid = true;
    }
    return fit;
}

IcpResult fit_last_stage(const std::vector<Eigen::Vector3d>& points, const Surface& reference,
                         const Eigen::Isometry3d& T_nominal_located, double distance,
                         const std::vector<Eigen::Vector3d>* normals) {
    IcpSettings is;
    is.max_distances = {distance};
    is.max_iterations = 20;
    return icp_point_to_plane(points, reference, T_nominal_located, is, normals);
}

namespace {

/// A scan's points relative to the nominal surfaces where `located` puts them (nominal where it is not
/// valid), with their normals, and the reference surfaces fitted on them alone.
struct OwnFit {
    std::vector<Eigen::Vector3d> pts, nrm;
    WorkpieceFit fit;
};

OwnFit own_fit(const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector3d>* normals,
               const WorkpieceFit& located, const Surface& reference, const WorkpieceFitSettings& wfs) {
    const Eigen::Isometry3d T_nominal_located =
        located.valid ? located.T_located_nominal.inverse() : Eigen::Isometry3d::Identity();
    OwnFit o;
    o.pts.reserve(points.size());
    for (const auto& p : points) o.pts.push_back(T_nominal_located * p);
    if (normals && normals->size() == points.size())
        for (const auto& n : *normals) o.nrm.push_back(T_nominal_located.linear() * n);
    o.fit = fit_reference_surfaces(o.pts, reference, wfs, o.nrm.empty() ? nullptr : &o.nrm);
    return o;
}

/// How far the own fit moves the points along the surfaces' normals (RMS over its points on them).
double moved_along_normals(const OwnFit& o, const Surface& reference) {
    // Each point against the reference where its own fit puts it: the own fit moves the part by
    // T_located_nominal, so the point sits at T_located_nominal^-1 p relative to the nominal surfaces. (Until
    // this test, the point was moved by T_located_nominal itself, away from the surfaces: a scan 1 mm off
    // moved its points 2 mm off, out of reach of the search, and only the points it slid along were counted.)
    const Eigen::Isometry3d back = o.fit.T_located_nominal.inverse();
    double sum = 0.0;
    std::size_t on = 0;
    for (const auto& p : o.pts) {
        const Eigen::Vector3d q = back * p;
        double d2 = 0.0;
        const int k = reference.nearest(q, &d2, o.fit.distance);
        if (k < 0) continue;
        const double along = (p - q).dot(reference.normals[k]);
        sum += along * along;
        ++on;
    }
    return on ? std::sqrt(sum / on) : 0.0;
}

}  // namespace

std::string part_disowns_scan(const std::vector<Eigen::Vector3d>& points,
                              const std::vector<Eigen::Vector3d>* normals, const WorkpieceFit& located,
                              const Surface& reference, const WorkpieceFitSettings& wfs) {
    const OwnFit o = own_fit(points, normals, located, reference, wfs);
    const WorkpieceFit& own = o.fit;
    char buf[240];
    if (own.inliers < wfs.min_inliers) {
        // Unconfirmed is not good enough for a lone fiducial: a look-alike puts the scan's points where the
        // part is not (measured: 8552 points in the part's region, none on its reference surfaces, the scan
        // 200 mm and 90 degrees off).
        std::snprintf(buf, sizeof buf,
                      "the part does not confirm it: %zu of its %zu points in the part's region lie on the "
                      "reference surfaces (needs %zu)",
                      own.inliers, o.pts.size(), wfs.min_inliers);
        return buf;
    }
    if (!located.valid) {
        // With the part not located from the scans together there is nothing else to hold this scan to: its
        // own points must fix the part in all six degrees of freedom (measured: seed 1320, 5 % outliers,
        // fiducial A's model mirrored: the mirrored model alone placed scan 2 224 mm and 178 degrees off,
        // where 1107 of its points lay on one plane that the reference surfaces slid onto, conditioning 0).
        if (own.conditioning < 0.2 * wfs.min_conditioning)
            return "the part does not confirm it: fitted on its points alone, " + own.reason;
        return {};
    }
    const double moved = moved_along_normals(o, reference);
    if (moved <= own_fit_limit_noises * wfs.noise) return {};
    std::snprintf(buf, sizeof buf, "the part it shows lies %.3g off the part the scans locate", moved);
    return buf;
}

double scan_part_offset(const std::vector<Eigen::Vector3d>& points,
                        const std::vector<Eigen::Vector3d>* normals, const WorkpieceFit& located,
                        const Surface& reference, const WorkpieceFitSettings& wfs) {
    if (!located.valid) return -1.0;
    const OwnFit o = own_fit(points, normals, located, reference, wfs);
    if (o.fit.inliers < wfs.min_inliers) return -1.0;
    return moved_along_normals(o, reference);
}

}  // namespace partloc
