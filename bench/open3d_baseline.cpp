#include "open3d_baseline.hpp"

#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/pipelines/registration/CorrespondenceChecker.h>
#include <open3d/pipelines/registration/Feature.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>
#include <open3d/utility/Random.h>

#include <algorithm>

namespace partloc::bench {

namespace reg = open3d::pipelines::registration;
using open3d::geometry::KDTreeSearchParamHybrid;
using open3d::geometry::PointCloud;

namespace {

struct Prepared {
    std::shared_ptr<PointCloud> full;  ///< ICP source or target
    std::shared_ptr<PointCloud> down;  ///< voxel-downsampled, with normals
    std::shared_ptr<reg::Feature> fpfh;
};

Prepared prepare_model(std::shared_ptr<PointCloud> model, double voxel) {
    Prepared p;
    p.full = model;
    p.down = model->VoxelDownSample(voxel);
    p.down->NormalizeNormals();  // averaged mesh normals, outward
    p.fpfh = reg::ComputeFPFHFeature(*p.down, KDTreeSearchParamHybrid(5.0 * voxel, 100));
    return p;
}

Prepared prepare_scan(const PointCloud& scan, double voxel) {
    Prepared p;
    p.full = std::make_shared<PointCloud>();
    p.full->points_ = scan.points_;
    p.full->EstimateNormals(KDTreeSearchParamHybrid(2.0 * voxel, 30));
    p.full->OrientNormalsTowardsCameraLocation(Eigen::Vector3d::Zero());  // the scanner sits at the origin
    p.down = p.full->VoxelDownSample(voxel);
    p.down->EstimateNormals(KDTreeSearchParamHybrid(2.0 * voxel, 30));
    p.down->OrientNormalsTowardsCameraLocation(Eigen::Vector3d::Zero());
    p.fpfh = reg::ComputeFPFHFeature(*p.down, KDTreeSearchParamHybrid(5.0 * voxel, 100));
    return p;
}

}  // namespace

MethodOutcome run_open3d(const Job& job, const Open3DSettings& settings) {
    open3d::utility::random::Seed(static_cast<int>(settings.seed));
    const double spacing = job.scanner.point_spacing.value_or(0.383);
    const double voxel =
        settings.voxel > 0 ? settings.voxel : std::max(2.5 * spacing, 0.025 * fiducial_diagonal(job));

    std::vector<Prepared> models;
    for (const auto& f : job.fiducials)
        models.push_back(prepare_model(fiducial_points(f, settings.model_spacing), voxel));

    MethodOutcome out;
    out.T_machine_scan.resize(job.scans.size());
    const Eigen::AlignedBox3d region = workpiece_region(job, spacing);
    auto merged = std::make_shared<PointCloud>();
    for (std::size_t i = 0; i < job.scans.size(); ++i) {
        const Scan& scan = job.scans[i];
        const Prepared s = prepare_scan(*scan.points, voxel);
        double best_fitness = 0.0;
        std::optional<Eigen::Isometry3d> best;
        for (std::size_t k = 0; k < models.size(); ++k) {
            const Prepared& m = models[k];
            const reg::CorrespondenceCheckerBasedOnEdgeLength edge(0.9);
            const reg::CorrespondenceCheckerBasedOnDistance distance(1.5 * voxel);
            const reg::RegistrationResult coarse = reg::RegistrationRANSACBasedOnFeatureMatching(
                *m.down, *s.down, *m.fpfh, *s.fpfh, settings.mutual_filter, 1.5 * voxel,
                reg::TransformationEstimationPointToPoint(false), 3, {edge, distance},
                reg::RANSACConvergenceCriteria(settings.ransac_iterations, settings.ransac_confidence));
            if (coarse.fitness_ <= 0.0) continue;
            const reg::RegistrationResult fine =
                reg::RegistrationICP(*m.full, *s.full, 0.4 * voxel, coarse.transformation_,
                                     reg::TransformationEstimationPointToPlane());
            if (fine.fitness_ > best_fitness) {
                best_fitness = fine.fitness_;
                const Eigen::Isometry3d T_scan_fiducial(fine.transformation_);
                best = fiducial_at(job.machine, job.fiducials[k], scan.axes) * T_scan_fiducial.inverse();
            }
        }
        out.T_machine_scan[i] = best;
        if (!best) continue;
        const Eigen::Isometry3d T = T_machine0_scan(job, scan, *best);
        for (const auto& q : scan.points->points_) {
            const Eigen::Vector3d p = T * q;
            if (region.contains(p)) merged->points_.push_back(p);
        }
    }
    if (merged->points_.empty()) {
        out.message = "no scan registered";
        return out;
    }
    // The part: one point per scan spacing, normals, point-to-plane ICP of the nominal reference surfaces,
    // coarse (5 mm, the size of a set-up error) then fine (3 scan spacings).
    merged = merged->VoxelDownSample(spacing);
    merged->EstimateNormals(KDTreeSearchParamHybrid(4.0 * spacing, 30));
    const auto ref = reference_points(job, spacing);
    reg::RegistrationResult r = reg::RegistrationICP(*ref, *merged, 5.0, Eigen::Matrix4d::Identity(),
                                                     reg::TransformationEstimationPointToPlane(),
                                                     reg::ICPConvergenceCriteria(1e-6, 1e-6, 100));
    r = reg::RegistrationICP(*ref, *merged, 3.0 * spacing, r.transformation_,
                             reg::TransformationEstimationPointToPlane(),
                             reg::ICPConvergenceCriteria(1e-6, 1e-6, 100));
    if (r.fitness_ <= 0.0) {
        out.message = "ICP of the reference surfaces found no correspondences";
        return out;
    }
    out.located = true;
    out.T_machine_workpiece = Eigen::Isometry3d(r.transformation_) * job.workpiece.T_machine_workpiece;
    return out;
}

}  // namespace partloc::bench
