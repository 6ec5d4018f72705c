#pragma once
// The virtual 3D scanner: Embree ray casting into the cell from any pose. The scanner sits at the origin of
// its own frame (the scan frame) and looks along its +z; +x is across the field, +y down it. A grid of rays
// through a plane at the working distance gives the requested point spacing there (a structured-light or
// laser scanner's fixed angular pattern).
#include <open3d/geometry/PointCloud.h>

#include <Eigen/Geometry>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "partloc/sim/cell.hpp"

namespace partloc::sim {

/// Defaults model the paper's NextEngine HD (§3.3, Table 1): wide range, 4,400 points per square inch.
struct ScannerSettings {
    double working_distance = 430.0;  ///< mm; where point_spacing holds (NextEngine wide mode: 17 in)
    double point_spacing = 0.383;  ///< mm between neighbouring rays at the working distance (25.4/sqrt(4400))
    double field_width = 256.0;    ///< mm across scanner x at the working distance (about 250 k points
    double field_height = 192.0;   ///< mm across scanner y  per scan; the NextEngine's is 343 x 257)
    double min_range = 250.0;      ///< mm; nearer returns are lost (depth of field)
    double max_range = 700.0;      ///< mm; farther returns are lost
    double noise_sigma = 0.13;     ///< mm, 1 sigma along the line of sight (0.381 mm accuracy as 3 sigma)
    double dropout = 0.02;         ///< fraction of returns lost at normal incidence
    double max_incidence_deg = 80.0;  ///< degrees between ray and surface normal beyond which nothing returns
    double dropout_exponent = 4.0;    ///< loss = dropout + (1 - dropout) (incidence / max_incidence)^exponent
    double outlier_fraction = 0.002;  ///< fraction of returns displaced along the ray (spurious returns)
    double outlier_min = 2.0;         ///< mm; outliers are displaced by outlier_min..outlier_max,
    double outlier_max = 25.0;        ///< mm  either way along the ray
    std::uint64_t seed = 1;           ///< same seed, same points
};

/// A cell frozen at one set of axis values, ready for ray casting. Build it once per axis value and scan it
/// from any number of poses; intersect() and scan() may be called from several threads at once.
class RayScene {
  public:
    /// Places every body at axis values q. Keeps a reference to `cell`, which must outlive the scene.
    /// Throws std::runtime_error when Embree fails.
    RayScene(const Cell& cell, const AxisValues& q);
    ~RayScene();
    RayScene(RayScene&&) noexcept;
    RayScene& operator=(RayScene&&) noexcept;
    RayScene(const RayScene&) = delete;
    RayScene& operator=(const RayScene&) = delete;

    struct Hit {
        double range = std::numeric_limits<double>::infinity();  ///< mm along the unit ray; inf: no hit
        int body = -1;                                           ///< index into cell().bodies
        int triangle = -1;                                       ///< triangle of that body's mesh
        Eigen::Vector3d normal =
            Eigen::Vector3d::Zero();  ///< unit geometric normal, machine frame, either side
        bool valid() const { return body >= 0; }
    };
    /// First surface along origin + t * direction, t > 0 (machine frame, mm; direction is normalised here).
    Hit intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction) const;

    const Cell& cell() const;
    const AxisValues& axes() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

/// One simulated scan.
struct SimulatedScan {
    std::shared_ptr<open3d::geometry::PointCloud> points;  ///< scan frame (= scanner frame), mm
    std::vector<int> body;              ///< per point: index into cell().bodies of the body the ray hit
    std::vector<int> triangle;          ///< per point: the triangle of that body's mesh
    std::vector<std::uint8_t> outlier;  ///< per point: 1 when displaced as a spurious return
    std::size_t rays = 0;               ///< rays cast
    std::size_t missed = 0;             ///< rays that hit nothing, or hit outside [min_range, max_range]
    std::size_t dropped = 0;            ///< returns lost to drop-out
};

/// Scans `scene` from T_machine_scanner. Each ray draws its noise from its own random stream keyed by
/// (settings.seed, ray index), so the result does not depend on the thread count.
SimulatedScan scan(const RayScene& scene, const Eigen::Isometry3d& T_machine_scanner,
                   const ScannerSettings& settings = {});

/// Scanner pose at `eye` looking at `target` (machine frame): scanner +z toward the target, +x
/// perpendicular to `up`, +y completing the right-handed frame (pointing away from `up`).
Eigen::Isometry3d look_at(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
                          const Eigen::Vector3d& up = Eigen::Vector3d::UnitZ());

}  // namespace partloc::sim
