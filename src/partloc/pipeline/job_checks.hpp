#pragma once
// Checks of a job against its own data (issue 27): the scans' size against the fiducials' in the job's units
// (before registering: what `partloc check` prints, and `run` warns of), and the located reference surfaces
// against the scans (after the part's fit: reference faces the scans show elsewhere), and each registered
// scan's part against the located part (after the fit: scans at other axis positions than the job says).
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "partloc/core/localize.hpp"
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

/// A sentence for each fiducial whose prepared model (`models`, in the job's order) maps onto itself by a
/// turn (issue 25: symmetric fiducials): it cannot place a scan alone; a scan needs another fiducial in view
/// that tells its turns apart.
std::vector<std::string> symmetry_warnings(const Job& job, const std::vector<PreparedModel>& models);
/// The same before the scans are measured (`partloc check`): each model prepared at 1/150 of its diameter.
std::vector<std::string> symmetry_warnings(const Job& job);

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

struct AxisCheckSettings {
    std::size_t points = 4000;  ///< of each scan's points, evenly spread, are looked up
    double band_noises = 3.0;   ///< a point lies on the reference surfaces within this many noises
    double min_turn_deg = 1.0;  ///< a turn of less is not told (the fit's own error)
    /// A turn is told when its points on the reference surfaces number at least `gain` times those at the
    /// axis values the job gives, plus `min_gain`, and at least `min_points`.
    double gain = 2.0;
    std::size_t min_gain = 30, min_points = 50;
};

/// A scan whose part lies turned about a rotary axis the workpiece moves with: its axis value is not the
/// one the job gives (left out, or mistyped).
struct TurnedScan {
    std::size_t scan = 0;
    std::string axis;
    double stated = 0.0;  ///< the axis value the job gives (degrees; 0 where it gives none)
    double agrees = 0.0;  ///< the value at which the scan's part lies on the located part
    std::size_t points_stated = 0, points_agree = 0;  ///< its sampled points on the reference surfaces
    std::string sentence() const;
};

/// Each registered scan (`T_machine_scan`, null where it is not registered) against the located part: its
/// points carried to the reference axis position by the job's axis values, and by other values of each
/// rotary axis the workpiece moves with (every 2 degrees, then finer about the best), counted on the
/// reference surfaces placed at `T_located_nominal` (machine0). A scan that lies on them far better at
/// another value is named, with the axis and the value (issue 27: `axes:` left out of the rotated scans put
/// the part three times into merged.ply and the stock). Nothing for a workpiece on no rotary axis.
std::vector<TurnedScan> turned_scans(const Job& job,
                                     const std::vector<const Eigen::Isometry3d*>& T_machine_scan,
                                     const Surface& reference, const Eigen::Isometry3d& T_located_nominal,
                                     double noise, const AxisCheckSettings& settings = {});

}  // namespace partloc
