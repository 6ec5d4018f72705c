#pragma once
// Checks of a job against its own data (issue 27): the scans' size against the fiducials' in the job's units
// (before registering: what `partloc check` prints, and `run` warns of), and the located reference surfaces
// against the scans (after the part's fit: reference faces the scans show elsewhere). The checks still to
// come need the registrations: scans at other axis positions without `axes`, a fiducial probed wrong.
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "partloc/core/surface.hpp"
#include "partloc/pipeline/job.hpp"

namespace partloc {

/// One scan as read: its valid points, their spacing (median nearest-neighbour distance, measured) and the
/// diagonal of their bounding box, in job units.
struct ScanSummary {
    std::size_t points = 0;
    double spacing = 0.0;
    double extent = 0.0;
};

/// Per scan of the job; the spacing measured on it unless `spacings` gives it (run_job's own measure).
std::vector<ScanSummary> summarise_scans(const Job& job, const std::vector<double>* spacings = nullptr);

struct UnitCheckSettings {
    /// A scan is plausible in a unit when its points span from `min_extent` to `max_extent` fiducials
    /// (median model diagonal) and lie at most `max_spacing` of a fiducial apart (it must show a fiducial
    /// with thousands of points). The simulated cells' scans span 6-10 fiducials: m, in and um for mm are
    /// told, cm is not.
    double min_extent = 0.5, max_extent = 300.0, max_spacing = 0.1;
};

/// A sentence for each scan whose size is implausible against the fiducials' in the job's units, naming
/// the unit in which it would be plausible ("did you mean units: m?") where one is.
std::vector<std::string> unit_warnings(const Job& job, const std::vector<ScanSummary>& scans,
                                       const UnitCheckSettings& settings = {});

struct ReferenceCheckSettings {
    double face_angle_deg = 20.0;  ///< reference samples of one face: neighbours whose normals turn less
    double min_points = 200;       ///< a face is judged on at least this many scan points
    double band_spacings = 10.0;   ///< points within this many of the larger of spacing and noise
    double offset_noises = 5.0;    ///< a face is off when its points' median lies farther than this
    double sheet_noises = 3.0;     ///< ... and they scatter about it as a sheet, less than this
};

/// The located reference surfaces against the scans (issue 27: "reference surfaces that are not the as-built
/// ones"): for each face of the reference samples (`points`, `normals`, nominal frame, `spacing` apart),
/// the scan points (machine frame, with normals) whose nearest sample on it lies within the band, square to
/// the face and within two spacings beside it, facing as it does. A face whose points lie as a sheet parallel
/// to it, offset by more than the noise allows, is a face the scans show elsewhere: the finished part's faces
/// given for the as-built ones. A sentence per such face (units `units`), empty when none.
std::vector<std::string> reference_offset_warnings(const std::vector<Eigen::Vector3d>& points,
                                                   const std::vector<Eigen::Vector3d>& normals,
                                                   const Surface& reference,
                                                   const Eigen::Isometry3d& T_located_nominal, double noise,
                                                   double spacing, const std::string& units,
                                                   const ReferenceCheckSettings& settings = {});

}  // namespace partloc
