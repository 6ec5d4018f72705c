#pragma once
// Open3D's standard global registration pipeline (the "Global registration" tutorial of Open3D 0.16), per
// scan and fiducial: voxel downsampling, normals, FPFH, RANSAC on feature matches with the edge-length
// (0.9) and distance checkers, point-to-plane ICP; among the fiducials the best ICP fitness wins. The
// workpiece: the registered scans' region points merged, point-to-plane ICP of the reference surfaces.
#include <cstdint>

#include "common.hpp"

namespace partloc::bench {

struct Open3DSettings {
    /// Voxel size (mm): max(2.5 x point spacing, 0.025 x the largest fiducial diagonal). The tutorial's
    /// other lengths follow from it: normals 2 voxels, FPFH 5 voxels, RANSAC distance 1.5 voxels,
    /// ICP 0.4 voxel.
    double voxel = 0.0;              ///< 0: from the rule above
    double model_spacing = 0.5;      ///< mm, Poisson-disk fiducial models (paper §3.2)
    int ransac_iterations = 100000;  ///< the tutorial's RANSACConvergenceCriteria(100000, 0.999)
    double ransac_confidence = 0.999;
    /// The tutorial sets mutual_filter=True; on these blocks of planes it keeps too few right matches (an
    /// isolated fiducial was missed with it and found without), so the better of the two is the default.
    bool mutual_filter = false;
    std::uint64_t seed = 1;
};

MethodOutcome run_open3d(const Job& job, const Open3DSettings& settings = {});

}  // namespace partloc::bench
