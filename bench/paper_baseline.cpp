#include "paper_baseline.hpp"

#include <stdexcept>

#ifdef PARTLOC_BENCH_WITH_PCL
#include "pcl/paper_pcl.hpp"
#endif

namespace partloc::bench {

#ifndef PARTLOC_BENCH_WITH_PCL

bool paper_pipeline_available() { return false; }

MethodOutcome run_paper(const Job&, const PaperSettings&) {
    throw std::runtime_error(
        "built without PCL: install libpcl-dev (PARTLOC_WITH_PCL=1 scripts/install-deps.sh) "
        "and reconfigure");
}

#else

namespace {
paper::Points to_points(const std::vector<Eigen::Vector3d>& v) {
    paper::Points out(v.size());
    for (std::size_t i = 0; i < v.size(); ++i)
        out[i] = {static_cast<float>(v[i].x()), static_cast<float>(v[i].y()), static_cast<float>(v[i].z())};
    return out;
}

Eigen::Isometry3d to_isometry(const paper::Matrix4& a) {
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(r, c) = a[4 * r + c];
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    // SVD-based estimators return a rotation to float precision; re-orthonormalise before use.
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(m.topLeftCorner<3, 3>(),
                                                Eigen::ComputeFullU | Eigen::ComputeFullV);
    T.linear() = svd.matrixU() * svd.matrixV().transpose();
    T.translation() = m.topRightCorner<3, 1>();
    return T;
}
}  // namespace

bool paper_pipeline_available() { return true; }

MethodOutcome run_paper(const Job& job, const PaperSettings& settings) {
    std::vector<paper::Points> models;
    std::vector<paper::Normals> normals;
    for (const auto& f : job.fiducials) {
        const auto m = fiducial_points(f, settings.model_spacing, true);
        models.push_back(to_points(m->points_));
        normals.push_back(to_points(m->normals_));
    }
    paper::ProcessorParams pp;
    pp.seed = settings.seed;

    MethodOutcome out;
    out.T_machine_scan.resize(job.scans.size());
    const double spacing = job.scanner.point_spacing.value_or(0.383);
    const Eigen::AlignedBox3d region = workpiece_region(job, spacing);
    std::vector<Eigen::Vector3d> merged;
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        const Scan& scan = job.scans[i];
        const auto fits = paper::fit_fiducials(to_points(scan.points->points_), models, normals, pp);
        std::size_t best = fits.size();
        for (std::size_t k = 0; k < fits.size(); ++k)
            if (fits[k].converged && (best == fits.size() || fits[k].metric > fits[best].metric)) best = k;
        if (best == fits.size() || fits[best].metric <= pp.metric_threshold) continue;  // §4: rejected
        // (2): T_r = T_f^-1 T_o T_d, here T_machine_scan = T_machine_fiducial(q) T_scan_fiducial^-1.
        const Eigen::Isometry3d T = fiducial_at(job.machine, job.fiducials[best], scan.axes) *
                                    to_isometry(fits[best].T_scan_model).inverse();
        out.T_machine_scan[i] = T;
        const Eigen::Isometry3d T0 = T_machine0_scan(job, scan, T);
        for (const auto& q : scan.points->points_) {
            const Eigen::Vector3d p = T0 * q;
            if (region.contains(p)) merged.push_back(p);  // §3.4.2: "combined and clipped"
        }
    }
    if (merged.empty()) {
        out.message = "no scan passed the metric threshold";
        return out;
    }
    const auto ref = reference_points(job, settings.model_spacing);
    const paper::PartFit fit =
        paper::fit_part(to_points(merged), to_points(ref->points_), paper::PartParams{});
    if (!fit.converged) {
        out.message = "ICP of the reference surfaces did not converge";
        return out;
    }
    out.located = true;
    out.T_machine_workpiece = to_isometry(fit.T_data_nominal) * job.workpiece.T_machine_workpiece;
    return out;
}

#endif

}  // namespace partloc::bench
