#pragma once
// The scan's registration (paper §3.4.1, Eq. 2): every fiducial in view, as one rigid constellation. Each
// candidate of each fiducial that passes its own checks is a hypothesis for where the scanner was; it
// predicts every other fiducial from its probed pose, and the scan corroborates or contradicts each
// prediction. The best hypothesis that nothing refutes, and that no other placement of like support rivals,
// registers the scan; its pose is then fitted on every fiducial it explains at once.
#include <Eigen/Geometry>
#include <cstddef>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/localize.hpp"

namespace partloc {

/// A fiducial where the machine holds it while the scan is taken.
struct PlacedFiducial {
    std::string name;
    const PreparedModel* model = nullptr;
    /// The probed pose moved by the fiducial's axes to the scan's axis values (fiducial_at).
    Eigen::Isometry3d T_machine_fiducial = Eigen::Isometry3d::Identity();
};

/// The constellation's tolerances. Lengths scale with the global fit's sampling (PreparedModel::sampling)
/// or the scan's noise (Scale::noise), as each field says; angles are degrees.
struct RegistrationSettings {
    /// Search every fiducial on its own (the rest together after the first), also where an earlier
    /// fiducial's fit already settles the scan (for tests that compare the two; slower, same placements).
    bool search_every_fiducial = false;
    /// Points per fiducial in the fits that place or judge a hypothesis (the final fit takes all): a thousand
    /// or two fix a pose far inside the tolerances below.
    std::size_t hypothesis_points = 1500;
    /// A hypothesis's joint refinement starts at this many samplings; kept when it moves the scan less than
    /// `refine_max_move` samplings.
    double refine_start = 0.5;
    double refine_max_move = 1.0;
    /// A predicted fiducial is contradicted when at least `contradiction_bins` of its ray bins were seen
    /// through and its violation exceeds `contradiction_violation` times LocalizeSettings::max_violation.
    std::size_t contradiction_bins = 20;
    double contradiction_violation = 4.0;
    /// Two hypotheses from different fiducials corroborate each other when they turn the scanner apart by
    /// less than `corroboration_deg` and move the source fiducial's centre by less than
    /// `corroboration_distance` samplings.
    double corroboration_deg = 2.0;
    double corroboration_distance = 2.0;
    /// Two placements are distinct (ambiguous when of like support) beyond `distinct_deg` or
    /// `distinct_distance` samplings.
    double distinct_deg = 1.0;
    double distinct_distance = 5.0;
    /// A lone fiducial's fit is rivalled by another fit with at least this fraction of its own support.
    double rival_support = 0.5;
    /// Two corroborated sets of fiducials disagree beyond `disagreement_noise` noise sigmas at the fiducial.
    double disagreement_noise = 3.0;
    /// A fiducial's own fit disagrees with the joint fit beyond `own_fit_noise` noise sigmas at its centre,
    /// or the turn that moves its rim (half its diameter) that far; its own fit starts at `own_fit_start`
    /// samplings.
    double own_fit_noise = 3.0;
    double own_fit_start = 0.5;
    /// A scan is placed only where, in every direction, at least this share of the final fit's information
    /// (least_share) comes from surfaces the scanner faces (VerifySettings::facing_cos). World 2: the three
    /// fits slid 0.4-0.8 mm along one axis had 0, 0 and 0.017; the least of 82 right ones 0.065.
    double min_facing_share = 0.04;
    /// Fit the scanner's scale beside the pose where two fiducials or more fix the scan (scale_fit.hpp); a
    /// scale off 1 by more than `max_scale_error` rejects the scan (a fiducial moved, or the scanner is far
    /// out of calibration). World 2's sensors are off by up to 0.12 %.
    bool fit_scale = true;
    double max_scale_error = 0.005;
    /// The fitted scale is used only when it differs from 1 by more than this many of its sigmas (from the
    /// noise); else the rigid fit stands. Seed 3 of our own cells (no scale error) fitted 0.99975 +- 0.00017
    /// on two fiducials that hardly fix it, and the part moved 0.15 mm; world 2's scales are 0.0002-0.0012
    /// off with sigmas of 1e-5 to 1e-4.
    double scale_significance = 3.0;
};

/// A hypothesis for the scanner's pose: one fiducial's candidate, judged against every fiducial.
struct Hypothesis {
    std::size_t source = 0;  ///< index of the fiducial whose candidate it is
    FiducialFit source_fit;  ///< that candidate
    Eigen::Isometry3d T_machine_scan_initial = Eigen::Isometry3d::Identity();  ///< from the source alone
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();          ///< refined on every fiducial
    double support = 0.0;                   ///< summed over the fiducials that pass where it puts them
    std::vector<std::size_t> explained;     ///< fiducials that pass their checks where it puts them
    std::vector<std::size_t> contradicted;  ///< fiducials the scan contradicts where it puts them
    std::vector<FiducialFit> judged;        ///< every fiducial judged where it puts it, in their order
    int corroborated = 0;                   ///< other fiducials' fits that put the scanner about here
    std::string refuted;                    ///< why it cannot be the scanner's pose; empty when it can
};

/// What one scan's registration found.
struct ScanRegistration {
    bool valid = false;
    std::string reason;  ///< why the scan is not registered; empty when valid
    /// Maps scan points to the machine frame at the scan's axis values (where the fixed bodies are).
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    std::vector<std::size_t> fiducials;  ///< the fiducials that fix the scan, in their order
    std::size_t source = 0;              ///< the fiducial whose candidate won
    bool corroborated = false;           ///< the winner is confirmed by a second fiducial
    double score = 0.0;                  ///< the winning candidate's (FiducialFit::score)
    double rmse = 0.0;                   ///< the final fit's RMS residual (job units)
    /// Information of T_machine_scan (twist [w, v], machine frame): JtJ / noise^2 of the final fit over every
    /// fiducial in `fiducials`, and each one's share of JtJ in their order. Zero and empty when one
    /// fiducial's fit placed the scan without the final fit.
    Matrix6d information = Matrix6d::Zero();
    /// The scanner's scale: a scan point p lies in the machine at T_machine_scan * (scale_centre + scale
    /// (p - scale_centre)), the centre amid the fiducials' points (so that T_machine_scan alone still places
    /// them as a rigid fit would). Fitted where two fiducials or more fix the scan
    /// (RegistrationSettings::fit_scale), else 1; `information` is then the pose's with the scale unknown.
    double scale = 1.0;
    Eigen::Vector3d scale_centre = Eigen::Vector3d::Zero();  ///< scan frame
    double scale_sigma = 0.0;  ///< 1 sigma of `scale` from the noise alone; 0 where not fitted
    std::vector<Matrix6d> JtJ_per_fiducial;
    std::vector<std::string> warnings;  ///< a fiducial left out (moved or probed wrong), even when not valid
    /// The fiducials this scan finds moved or probed wrong: each one not where its probed pose puts it while
    /// at least two others agree without it.
    std::vector<std::size_t> moved;
    std::vector<FiducialFit> fits;  ///< each fiducial's best fit, or how it was judged, in their order
    std::vector<Hypothesis> hypotheses;
};

/// Why the fiducials `placing` (indices into `fiducials`) cannot place a scan together: a turn of the
/// machine that maps each of them onto itself (symmetry.hpp); empty when they fix all six degrees of freedom.
std::string symmetry_reason(const std::vector<std::size_t>& placing,
                            const std::vector<PlacedFiducial>& fiducials);

/// Registers one scan by the fiducials placed at its axis values (all with the same PreparedModel::sampling).
ScanRegistration register_scan(const PreparedScan& scan, const std::vector<PlacedFiducial>& fiducials,
                               const LocalizeSettings& localize, const RegistrationSettings& settings = {});

// The steps of register_scan, for tests and for callers that build their own search.

/// Judges every fiducial where T_machine_scan puts it and fills h's support, explained, contradicted and
/// judged; returns whether the source fiducial itself passes there.
bool judge_hypothesis(Hypothesis& h, const Eigen::Isometry3d& T_machine_scan, const PreparedScan& scan,
                      const std::vector<PlacedFiducial>& fiducials, const LocalizeSettings& localize,
                      const RegistrationSettings& settings);

/// Whether h alone settles the scan, so that the fiducials not yet searched need no search: a second
/// fiducial passes, none is contradicted, and each one not searched passes too or shows nothing there.
bool settles(const Hypothesis& h, const std::vector<char>& searched, const LocalizeSettings& localize,
             const RegistrationSettings& settings);

/// Counts, for each hypothesis, the others from other fiducials that put the scanner about where it does, and
/// refutes those that the scan contradicts with no corroboration, or under which no fiducial passes.
void corroborate_and_refute(std::vector<Hypothesis>& hyps, const std::vector<PlacedFiducial>& fiducials,
                            const RegistrationSettings& settings);

/// The hypothesis to register by: corroborated ones first, then by support; null when all are refuted.
const Hypothesis* best_hypothesis(const std::vector<Hypothesis>& hyps);

/// Why the winner `top` cannot register the scan for a rival among `hyps` (two placements of like support,
/// two corroborated sets of fiducials that disagree, a lone fit against another fit elsewhere, one fiducial
/// against another); empty when none.
std::string rival_reason(const Hypothesis& top, const std::vector<Hypothesis>& hyps,
                         const std::vector<PlacedFiducial>& fiducials, double noise,
                         const LocalizeSettings& localize, const RegistrationSettings& settings);

}  // namespace partloc
