#pragma once
// The processor (paper §3.4.1): for one scan and one fiducial, a global fit with no initial guess (PPF
// voting), a fine least-squares fit (point-to-plane ICP) of each candidate, verification, and a decision
// with its reason.
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/cell_key.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/ppf.hpp"
#include "partloc/core/radius_grid.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/core/symmetry.hpp"
#include "partloc/core/verify.hpp"

namespace partloc {

/// Scale of a job: every radius and threshold follows from these two numbers (issue 4: parameters from
/// the scanner's specification or, when absent, from the data).
struct Scale {
    double spacing = 0.0;  ///< scan point spacing (job units)
    double noise = 0.0;    ///< scan noise, 1 sigma (job units)
};

/// A scan ready for fitting: its points, a search structure and a coarse oriented copy for the global fit.
struct PreparedScan {
    std::shared_ptr<open3d::geometry::PointCloud> cloud;  ///< valid points, scan frame (no normals)
    std::shared_ptr<RadiusGrid> grid;                     ///< over cloud's points
    /// Every sparse_stride-th point of `cloud` (by their order) and its grid, for the screening of the global
    /// fit's candidates, which takes a subsample of the points around each; the same as cloud and grid on a
    /// small scan (stride 1).
    std::shared_ptr<open3d::geometry::PointCloud> sparse;
    std::shared_ptr<RadiusGrid> sparse_grid;
    std::size_t sparse_stride = 1;
    std::vector<Eigen::Vector3d> coarse_points, coarse_normals;  ///< at the PPF sampling
    Eigen::Vector3d viewpoint = Eigen::Vector3d::Zero();         ///< scanner position, scan frame
    Scale scale;
    /// Normals (either sign) of cloud's points for the scan's pose fits (fit_scan_pose), each computed the
    /// first time a fit takes its point and kept: the hypotheses' fits, the joint fit and the fiducials' own
    /// fits take mostly the same points. Only the points near the fiducials are ever asked for (a few tens
    /// of thousands), so they are kept by point index, not in an array as long as the scan (48 MB a scan of
    /// 2 M points). Filled through a const PreparedScan: one scan's fits run one after another, never at
    /// once.
    struct PointNormals {
        cells::KeyIndex at;  ///< point index -> its place in `normals`
        std::vector<Eigen::Vector3d> normals;
    };
    std::shared_ptr<PointNormals> fit_normals;
};

/// A search tree on the scan, and for the global fit a voxel grid at `sampling` with normals oriented to the
/// viewpoint.
PreparedScan prepare_scan(const open3d::geometry::PointCloud& points, const Scale& scale, double sampling,
                          const Eigen::Vector3d& viewpoint);

/// A fiducial (or any rigid model) ready for fitting: dense oriented samples and the PPF table.
struct PreparedModel {
    std::string name;
    Surface dense;                  ///< for the fine fit and the verification
    std::shared_ptr<PpfModel> ppf;  ///< for the global fit
    double sampling = 0.0;          ///< PPF sampling (job units)
    Symmetry symmetry;              ///< the turns that map `dense` onto itself (symmetry.hpp)
};

/// What a scanner can see of a model, as prepare_model's `dense` surface: a mesh's samples `spacing` apart
/// that can be seen from outside it, or the points as they are; unit normals. Throws std::invalid_argument
/// when the model has neither triangles nor points.
Surface model_surface(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                      const open3d::geometry::PointCloud* points, double spacing);

/// Samples the model (a mesh by Poisson disk at `dense_spacing`, or points with normals as they are) and
/// builds its PPF table at `sampling`; finds its self-symmetries.
PreparedModel prepare_model(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                            const open3d::geometry::PointCloud* points, double dense_spacing,
                            double sampling);

/// The outcome of fitting one fiducial to one scan.
struct FiducialFit {
    std::string fiducial;
    bool valid = false;
    std::string reason;  ///< why it is not valid; empty when valid
    Eigen::Isometry3d T_scan_fiducial = Eigen::Isometry3d::Identity();
    double rmse = 0.0;             ///< RMS point-to-surface distance of the inliers (job units)
    double coverage = 0.0;         ///< fraction of the model surface facing the scanner that was observed
    double violation = 0.0;        ///< fraction of the observed model surface the scanner saw through
    double conditioning = 0.0;     ///< smallest eigenvalue of the normalised fit information, 0..1/3
    double spread = 0.0;           ///< smallest eigenvalue of the inliers' mean n n^T, 0..1/3
    double score = 0.0;            ///< coverage * (1 - violation)
    std::size_t inliers = 0;       ///< scan points on the model surface
    double overflow = 0.0;         ///< points continuing the model's facing faces past its edges, per inlier
    std::size_t observed = 0;      ///< ray bins of model surface observed (see Verification)
    std::size_t seen_through = 0;  ///< ray bins of model surface the scanner saw through
    int candidates = 0;            ///< global-fit candidates examined
    /// False: not searched on its own, but judged where another fiducial's fit put the scanner (the scan's
    /// placement needed no search of it).
    bool searched = true;
    /// Sum of J J^T over the inliers in the fiducial frame, J = [p x n; n]; information = JtJ / noise^2.
    Matrix6d JtJ = Matrix6d::Zero();
    Matrix6d JtJ_facing = Matrix6d::Zero();  ///< Verification::JtJ_facing (the same frame)
    std::size_t weakest_observed = 0;        ///< Verification::weakest_observed
    std::size_t weakest_against = 0;         ///< Verification::weakest_against
};

struct LocalizeSettings {
    int verified = 3;  ///< of the global fit's candidates, the best screened refined finely and verified
    double min_coverage = 0.30;       ///< of the model surface facing the scanner
    double max_violation = 0.05;      ///< of nearby points seen inside the model
    double min_conditioning = 0.003;  ///< a plane alone gives 0; a corner about 0.1-0.3
    double max_overflow = 0.04;       ///< points continuing the model's faces past its edges, per inlier
    std::size_t min_inliers = 100;
    /// RMS residual at most this fraction of the inlier distance (3 noise sigmas and the model's sampling):
    /// about 1/3 for Gaussian noise, 0.58 for residuals spread evenly, as a wrong fit's are.
    double max_rmse = 0.5;
    double ambiguity = 0.8;  ///< a distinct pose with this fraction of the best inliers: ambiguous
    /// A fiducial's own fit is rejected ("slides", slide_refutation) when, of the ray bins of the faces that
    /// hold its least held direction (Verification::weakest_observed), at least min_weakest_against and
    /// more than max_weakest_against of them contradict it: those faces are not where the fit puts them,
    /// while the rest of the fiducial, which does not fix that direction, fits.
    std::size_t min_weakest_against = 5;
    double max_weakest_against = 0.3;
    /// Restarts of an accepted fit along its least held direction, 1..slide_restarts samplings each way
    /// (0: none). A restart that ends within slide_distance samplings and slide_angle_deg is the same pose;
    /// one apart that explains more of the scan (support) replaces the fit, and of the two the better is
    /// rejected ("slides") when the other has slide_tie of its support.
    int slide_restarts = 2;
    double slide_distance = 0.25;
    double slide_angle_deg = 0.5;
    double slide_tie = 0.97;
    /// Points around a candidate that its screening fit and its fine fit take, and its polish at most (before
    /// those far from the surface are dropped): a thousand or two fix a pose far inside the checks above.
    std::size_t screen_points = 1500;
    std::size_t fine_points = 1500;
    std::size_t polish_points = 8000;
};

/// Support of a fit: the points on the model, weighted by coverage and the absence of see-through.
double support(const FiducialFit& fit);

/// Every candidate pose of `model` in `scan` after the fine fit and the verification: those that pass the
/// local checks first, then by support. Ambiguity is left to the caller.
std::vector<FiducialFit> fit_candidates(const PreparedScan& scan, const PreparedModel& model,
                                        const LocalizeSettings& settings);
/// The same from global-fit candidates already found (ppf_detect of several models in one pass).
std::vector<FiducialFit> fit_candidates(const PreparedScan& scan, const PreparedModel& model,
                                        const LocalizeSettings& settings,
                                        const std::vector<PoseCandidate>& candidates);

/// The verification's tolerances for `model` in `scan`: a point is on the surface within
/// sqrt((3 noise)^2 + spacing^2 / 2), spacing the model's dense samples' (model.dense.spacing, not
/// PreparedModel::sampling); ray bins twice the coarser of that spacing and the scan's.
VerifySettings verify_settings(const PreparedScan& scan, const PreparedModel& model);

/// Why a fiducial's own fit is refuted along its least held direction (LocalizeSettings::
/// min_weakest_against, max_weakest_against), or empty. fit_candidates applies it to every fine fit;
/// evaluate_model does not: at a pose that other fiducials set, disagreement is the caller's to judge.
std::string slide_refutation(const FiducialFit& fit, const LocalizeSettings& settings);

/// Judges `model` at a given pose in the scan (no fitting): where another fiducial says it must be.
FiducialFit evaluate_model(const PreparedScan& scan, const PreparedModel& model,
                           const Eigen::Isometry3d& T_scan_model, const LocalizeSettings& settings);

/// A scan's pose fitted to every fiducial in view at once (issue 4: every fiducial in view counts).
struct ScanPoseFit {
    bool valid = false;
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    /// Sum of J J^T over the inliers in the machine frame, twist [w, v]; information = JtJ / noise^2.
    Matrix6d JtJ = Matrix6d::Zero();
    double rmse = 0.0;
    std::size_t inliers = 0;
    std::vector<std::size_t>
        points;  ///< scan points taken near each fiducial's surface, in the models' order
    /// Each model's share of JtJ (the same frame and twist), in the models' order: how much each fiducial
    /// holds each direction of the fit, to carry a fiducial's probing error into the scan's pose.
    std::vector<Matrix6d> JtJ_per_model;
    /// The part of JtJ (sum of JtJ_per_model) over the points the scanner faces (VerifySettings::facing_cos).
    Matrix6d JtJ_facing = Matrix6d::Zero();
    /// The scan points the fit took (scan frame, in the models' order as `points` counts them) and their
    /// normals (either sign): for a fit of the scanner's scale beside the pose (scale_fit.hpp).
    std::vector<Eigen::Vector3d> source, source_normals;
    double inlier_distance = 0.0;  ///< the last stage's correspondence distance
};

/// The fiducials' dense samples at their machine poses as one surface, the target of fit_scan_pose: the
/// same for every start in a scan, so built once per scan and set of fiducials.
Surface make_pose_target(const std::vector<const PreparedModel*>& models,
                         const std::vector<Eigen::Isometry3d>& T_machine_model);

/// Point-to-plane fit of the scan to all `models` at their machine poses `T_machine_model` (at the scan's
/// axis values), from `init` (T_machine_scan, e.g. from one fiducial). `start_distance`: the first stage's
/// correspondence distance (0: a quarter of the sampling, for a start that is already close). `target`:
/// make_pose_target(models, T_machine_model) where the caller keeps it; null builds it.
/// `max_points_per_model`: when > 0, the points taken near each fiducial are thinned (every k-th) to at most
/// this many, for a fit that only places or judges a hypothesis; its JtJ is then that of the subsample.
ScanPoseFit fit_scan_pose(const PreparedScan& scan, const std::vector<const PreparedModel*>& models,
                          const std::vector<Eigen::Isometry3d>& T_machine_model,
                          const Eigen::Isometry3d& init, const LocalizeSettings& settings,
                          double start_distance = 0.0, const Surface* target = nullptr,
                          std::size_t max_points_per_model = 0);

/// Fits `model` to `scan`: global fit, fine fit of the best candidates, verification, decision; a second
/// distinct pose with nearly the best support makes the answer ambiguous, and it is rejected.
FiducialFit localize_model(const PreparedScan& scan, const PreparedModel& model,
                           const LocalizeSettings& settings);

}  // namespace partloc
