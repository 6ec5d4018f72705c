#pragma once
// The part (paper §3.4.2): the registered scans' workpiece points, the choice of the scans that the part's
// fit takes, and the fit of the nominal reference surfaces to their merged points.
#include <open3d/geometry/PointCloud.h>

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/localize.hpp"
#include "partloc/core/radius_grid.hpp"
#include "partloc/core/register_scan.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/core/workpiece_fit.hpp"
#include "partloc/pipeline/config.hpp"

namespace partloc {

/// What one registered scan brings to the part, built once from its registration.
struct ScanEvidence {
    Scale scale;
    /// The scan's points in the workpiece's region, machine0 (empty when fewer than
    /// PartSettings::min_region_points); null when the scan is not registered. Normals facing the scanner are
    /// computed where they are used (normals_at); a zero normal is one not computed yet.
    std::shared_ptr<open3d::geometry::PointCloud> workpiece_points;
    bool sees_part = false;                         ///< it had points in the workpiece's region
    Eigen::Vector3d eye = Eigen::Vector3d::Zero();  ///< the scanner, machine0
    double normal_radius = 0.0;                     ///< job units
    int normal_neighbours = 20;
    std::shared_ptr<RadiusGrid> grid;  ///< normals_at's neighbour grid over workpiece_points, once asked

    bool has_points() const { return workpiece_points && !workpiece_points->points_.empty(); }
    /// Computes the normals of workpiece points `idx` that have none yet: the same normals whenever asked
    /// (from all of the scan's workpiece points around each).
    void normals_at(const std::vector<std::size_t>& idx);
    void all_normals();
};

/// The scan's evidence: its points (scan frame) that lie in `region` (machine0) once moved there by
/// T_machine0_scan, with the scanner's position `viewpoint` (scan frame).
ScanEvidence scan_evidence(const open3d::geometry::PointCloud& points, const Scale& scale,
                           const Eigen::Isometry3d& T_machine0_scan, const Eigen::Vector3d& viewpoint,
                           const Eigen::AlignedBox3d& region, const PartSettings& settings);

/// Which registered scans the part's fit takes; the outcome of each scan for the part.
struct PartSelection {
    std::vector<char> registered;       ///< the registration stands
    std::vector<char> in_fit;           ///< in the part's fit (meaningful for registered scans)
    std::vector<std::string> rejected;  ///< why a registration was taken back; empty where it was not
    std::vector<std::string> warnings;  ///< per scan, for the person (seen nothing of the part, left out)
    std::vector<double> sigma;          ///< each scan's registration uncertainty at the part (1 sigma)
    double sigma_limit = 0.0;           ///< beyond it a scan is left out of the fit
    std::string none_left;              ///< why no scan is left, when none is

    bool any_registered() const;
    bool operator==(const PartSelection& o) const { return registered == o.registered && in_fit == o.in_fit; }
};

/// The part's fit from the merged points of the scans it takes.
struct PartFit {
    bool valid = false;
    std::string reason;  ///< why the part is not located; empty when valid
    PartSelection selection;
    WorkpieceFitSettings settings;  ///< with the scans' noise and spacing
    WorkpieceFit fit;               ///< the reference surfaces' fit (its last stage on every nearby point)
    std::size_t fit_points = 0;     ///< points the fit's last stage took
    std::shared_ptr<open3d::geometry::PointCloud> merged;  ///< the merged points of the scans in the fit
    /// The merged points of every registered scan (merged.ply and the stock are made from these).
    std::shared_ptr<open3d::geometry::PointCloud> all_registered;
    std::vector<int> merged_scan, all_registered_scan;  ///< per point of merged / all_registered, its scan
    /// Each scan's points near the located reference surfaces, with normals (null where it has none or is
    /// not in the fit): what the last stage took, and what the uncertainty refits.
    std::vector<std::shared_ptr<open3d::geometry::PointCloud>> on_reference;
};

/// The inputs of the part's stage.
struct PartInputs {
    const std::vector<ScanRegistration>* registrations = nullptr;
    std::vector<ScanEvidence>* evidence = nullptr;
    /// Per scan, where the reference surfaces' centre is at the scan's axis values (machine frame).
    std::vector<Eigen::Vector3d> part_at_scan;
    std::vector<std::string> fiducial_names;  ///< in the job's order
    const Surface* reference = nullptr;       ///< nominal reference surfaces, machine0
    double spacing = 0.0;                     ///< the scans' median point spacing
};

/// The selection before any fit: each registration as it stands, less the scans that only one fiducial's
/// uncorroborated fit placed and that put nothing in the workpiece's region. Needs no reference surfaces.
PartSelection first_selection(const PartInputs& in);

/// Chooses the scans, from `selection` (first_selection), and fits the reference surfaces: the registrations
/// weighed by how well they hold the part, then a selection that depends on the fit, run until the fit no
/// longer changes it (README, "The part").
PartFit fit_part(const PartInputs& in, PartSelection selection, const Config& config);

/// A scan in the fit whose own points show the part elsewhere than the part located from all of them.
struct ScanOffPart {
    std::size_t scan = 0;
    double moved = 0.0;  ///< scan_part_offset: RMS along the reference surfaces' normals (job units)
};

/// The scans in `p`'s fit, however many fiducials placed them, whose part lies more than own_fit_limit_noises
/// off the located part (scan_part_offset, the lone-fiducial test of next_selection): together they do not
/// show one part. The part moved in its clamp between scans, or a scan's axis values are not the job's and no
/// turn about one axis explains it (issue 27: seed 8 with `axes` left out registered a scan at A = 90 as at 0
/// with both fiducials, and the part was located 1.56 mm off between the two). Most-off first.
std::vector<ScanOffPart> scans_off_part(const PartFit& p, const PartInputs& in, const PartSettings& settings);

/// The registered scans' workpiece points (those in the fit only, when fit_only), thinned by their order to
/// at most PartSettings::merged_points, statistical outliers removed. Never thinned on a voxel grid: on a
/// face nearly parallel to its planes (a part squared to the machine) which points it keeps depends on the
/// noise. `scan_of`, when given, receives each kept point's scan index.
std::shared_ptr<open3d::geometry::PointCloud> merge_scans(std::vector<ScanEvidence>& evidence,
                                                          const PartSelection& selection, bool fit_only,
                                                          const PartSettings& settings,
                                                          std::vector<int>* scan_of = nullptr);

}  // namespace partloc
