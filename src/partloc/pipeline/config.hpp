#pragma once
// Every tuning constant of a job, in one place (RunSettings::config). Lengths are not given in job units:
// each is a multiple of a scale that the job's own data sets, as its comment says (the scans' point spacing
// and noise, the global fit's sampling, a model's diameter), so that the same configuration serves a cell in
// millimetres and one in metres.
#include <cstddef>

#include "partloc/core/datum_fit.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/core/register_scan.hpp"
#include "partloc/core/stock.hpp"
#include "partloc/core/workpiece_fit.hpp"
#include "partloc/pipeline/machining.hpp"

namespace partloc {

/// Parameters from the data: how each scan's scale is measured and how the models are sampled.
struct ScaleSettings {
    std::size_t measure_points = 3000;  ///< points a scan's spacing and noise are measured on
    /// Smoothed or quantised data can show almost no scatter: the noise is never taken below this many
    /// spacings.
    double min_noise = 0.05;
    /// The global fit's sampling: this fraction of the fiducials' median diameter (Drost et al.: 0.03-0.05),
    /// never finer than `sampling_spacings` times the coarsest scan's spacing.
    double sampling_diameter = 0.04;
    double sampling_spacings = 2.5;
    /// A fiducial's dense samples: its diameter divided by this, never finer than the scans' median spacing.
    double dense_divisions = 150.0;
    /// The reference surfaces' samples: their diagonal divided by this, never finer than that spacing.
    double reference_divisions = 400.0;
    std::size_t min_scan_points = 100;  ///< a scan with fewer valid points is rejected
};

/// The part (paper §3.4.2): which registered scans its fit takes, and how their points are merged.
struct PartSettings {
    /// At most this many merged points go to the part's fit (every k-th, by their order), and its last stage
    /// looks again at most at `reference_points` of the scans' points near the reference surfaces.
    std::size_t merged_points = 150000;
    std::size_t reference_points = 1500000;
    /// The last stage takes the points within this many of the fit's last correspondence distance.
    double reference_reach = 2.0;
    /// A scan showing fewer points than this in the workpiece's region shows nothing of the part.
    std::size_t min_region_points = 10;
    /// Statistical outliers of the merged points: `outlier_neighbours` neighbours, `outlier_sigmas` sigmas,
    /// on more than `outlier_min_points` points.
    int outlier_neighbours = 20;
    double outlier_sigmas = 2.5;
    std::size_t outlier_min_points = 30;
    /// The scans' normals: from the neighbours within this many spacings, at most `normal_neighbours`.
    double normal_radius = 2.5;
    int normal_neighbours = 20;
    /// A scan whose registration leaves the part uncertain (1 sigma) by more than `loose` noise sigmas is
    /// rejected; one uncertain by more than `left_out_median` times the scans' median (and `left_out_floor`
    /// noise sigmas) stays registered but out of the part's fit.
    double loose = 1.0;
    double left_out_median = 3.0;
    double left_out_floor = 0.1;
    /// A scan in the fit that shows the part elsewhere (scans_off_part, own_fit_limit_noises) is judged on at
    /// most this many of its workpiece points, evenly spread.
    std::size_t off_part_points = 20000;
};

/// The uncertainty's jackknife (pipeline/uncertainty.hpp): at most about this many of each scan's points
/// are refitted: of its points near the reference surfaces, or of all its workpiece points for the datums.
struct UncertaintySettings {
    std::size_t scan_points = 30000;
    std::size_t datum_scan_points = 8000;
};

/// What report.html draws.
struct ReportSettings {
    /// Registered workpiece points in the 3D view (an even subsample; 12 bytes each in the page, base64).
    std::size_t view_points = 60000;
};

struct Config {
    ScaleSettings scale;
    /// Each fiducial's candidates from the global search: fine fit and verification (core/localize.hpp).
    LocalizeSettings candidates;
    RegistrationSettings registration;  ///< the constellation (core/register_scan.hpp)
    PartSettings part;
    /// The reference surfaces' fit; its noise and spacing are set from the scans.
    WorkpieceFitSettings workpiece;
    DatumFitSettings datums;  ///< the 3-2-1 fit; its noise and spacing are set from the scans
    StockSettings stock;      ///< its spacing is set from the scans
    UncertaintySettings uncertainty;
    MachiningSettings
        machining;  ///< the allowance and placement; spacing, noise and the job's fields set per job
    ReportSettings report;
};

}  // namespace partloc
