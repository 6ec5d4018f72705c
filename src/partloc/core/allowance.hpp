#pragma once
// How much material is left on the final part (SPEC "Machining"): at each sample of the final part's surface,
// the distance along its outward normal to the as-built surface that the scans show, positive where stock
// remains, negative where the final part breaks out of it, and *unscanned* (never a number) where no scan saw
// the stock there.
//
// The as-built surface at a sample is found among the merged scan points around the sample's normal line
// (within `smoothing` of it) whose normals face the same way: the nearest such sheet along the line, a plane
// fitted to it (least squares, refitted once without the points beyond three noise), and the line's crossing
// of that plane. The sign comes from the normals (which side of the stock faces out), never from ray parity
// (Open3D's signed distance has known sign errors: its issues #6919, #5669, #5105). The plane averages
// some 200 points, so that the scanner's noise does not pass for a break-out: its standard error is about a
// fifteenth of the noise, and it follows a tilted stock face exactly. The fitted plane is kept per sample:
// the placement (placement.hpp) moves the part against these planes.
#include <Eigen/Geometry>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/radius_grid.hpp"

namespace open3d::geometry {
class TriangleMesh;
}

namespace partloc {

struct AllowanceSettings {
    double spacing = 0.0;  ///< scanner's point spacing (job units), required; the final part is sampled at it
    double noise = 0.0;    ///< scanner's 1-sigma noise (job units), required
    double smoothing =
        8.0;  ///< radius about the normal line of the points a sample's plane takes, in spacings
    /// Where the surface is as flat farther out, the plane takes the points within this radius (spacings).
    double smoothing_max = 20.0;
    /// Farthest the as-built surface is looked for along a sample's normal, either way (job units); 0: 5 % of
    /// the final part's bounding-box diagonal.
    double reach = 0.0;
    /// Points whose normals turn further from the sample's belong to another face: 15 degrees leaves out the
    /// points of the next face at the stock's edges, whose estimated normals turn by more (measured:
    /// tests/test_allowance.cpp; 30 and 45 degrees biased the least allowance near edges by 0.03-0.04 mm).
    double max_normal_angle_deg = 15.0;
    /// A sample is scanned when its plane holds at least this fraction of the points a fully scanned disc of
    /// radius `smoothing` has (pi * smoothing^2 points at one per spacing^2).
    double min_support = 0.25;
    double face_angle_deg = 20.0;  ///< adjacent triangles of the final part bent less than this are one face
};

/// A face (or region) of the final part: triangles joined across edges bent less than face_angle_deg.
struct PartFace {
    int id = 0;                                        ///< 1, 2, ... by decreasing area
    double area = 0.0;                                 ///< job units^2
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();  ///< area-weighted mean outward normal (nominal frame)
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< area-weighted centroid (nominal frame)
};

/// The final part's surface samples, in the frame of its mesh, with each sample's face.
struct PartSamples {
    std::vector<Eigen::Vector3d> points, normals;
    std::vector<int> face;  ///< index into faces
    std::vector<PartFace> faces;
};

/// Samples `mesh` (closed, outward triangles) at about one per spacing^2 (Poisson disk, deterministic) and
/// splits it into faces. Throws std::invalid_argument for a mesh without triangles or spacing <= 0.
PartSamples sample_part(const open3d::geometry::TriangleMesh& mesh, double spacing, double face_angle_deg);

/// A least-squares plane through scan points, with what its height's standard error needs.
struct StockPlaneFit {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero(), normal = Eigen::Vector3d::Zero();
    double sigma = 0.0;      ///< robust scatter of the kept points about the plane (job units)
    std::size_t points = 0;  ///< 0: no fit
    /// The kept points' spread in the plane: its axes and their sums of squares about the centre.
    Eigen::Vector3d axis[2] = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    double spread[2] = {0.0, 0.0};

    /// The standard error of the plane's height at q (the prediction variance of a least-squares plane,
    /// sigma^2 (1/N + sum_k (d . e_k)^2 / S_k) for the offset d from the centre, sigma at least
    /// sigma_floor): small at the centre, large beyond the points.
    double height_se(const Eigen::Vector3d& q, double sigma_floor) const;
};

/// The merged scan points with outward unit normals, with a search over them, and the flat regions of the
/// stock's surface they show.
struct ScannedStock {
    std::vector<Eigen::Vector3d> points, normals;
    RadiusGrid grid;
    /// Each point's region (-1: none): points joined to neighbours (within 2.5 spacings) whose normals turn
    /// less than max_normal_angle_deg and that lie within three noise of the region's plane; the regions
    /// of at least the support of a sample's plane, each with its plane. At the edges of a face a sample's
    /// own disc of points is a half or a quarter, and its plane tilts with the noise: a face-wide plane,
    /// where it agrees, is exact there (the least allowance per face of a tilted stock box at noise 0.13 mm
    /// was 0.02-0.03 mm off with discs of up to 20 spacings; tests/test_allowance.cpp).
    std::vector<int> region;
    std::vector<StockPlaneFit> regions;
};
/// The search over them in cells of half the narrow plane's radius (the queries are of one and 2.5 such
/// radii: larger cells than RadiusGrid's usual tenth visit far fewer empty cells around a surface), and
/// the regions. Throws std::invalid_argument when the counts differ or the settings have no spacing.
ScannedStock make_scanned_stock(std::vector<Eigen::Vector3d> points, std::vector<Eigen::Vector3d> normals,
                                const struct AllowanceSettings& settings);

/// The as-built surface near one sample, as a plane: allowance = (centre - p) . normal / (n . normal).
struct StockPlane {
    bool scanned = false;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();  ///< outward
    int points = 0;
};

/// The allowance along the line p + t n against a plane; NaN when the line runs along it.
double allowance_on_plane(const StockPlane& plane, const Eigen::Vector3d& p, const Eigen::Vector3d& n);

struct FaceAllowance {
    int id = 0;
    std::size_t samples = 0, unscanned = 0;
    double min = std::numeric_limits<double>::quiet_NaN(), mean = min, max = min;
    Eigen::Vector3d min_at = Eigen::Vector3d::Zero();  ///< machine frame
    double unscanned_fraction() const { return samples ? double(unscanned) / double(samples) : 0.0; }
};

/// The map at one pose of the final part: per sample (PartSamples' order) the allowance, NaN where unscanned.
struct AllowanceMap {
    std::vector<Eigen::Vector3d> points, normals;  ///< the samples where the part is (machine frame)
    std::vector<double> allowance;
    std::vector<StockPlane> planes;
    std::vector<FaceAllowance> faces;  ///< PartSamples::faces' order
    FaceAllowance all;                 ///< the whole surface (id 0)
    int min_face = -1;                 ///< index into faces of the least allowance; -1 when nothing scanned
};

/// Measures the allowance of `part`'s samples moved by T (its mesh frame to the machine frame).
AllowanceMap measure_allowance(const PartSamples& part, const Eigen::Isometry3d& T, const ScannedStock& stock,
                               const AllowanceSettings& settings);

/// The map of the part moved to T against the planes measured before (no new search): exact where the
/// as-built surface is the plane near each sample, and so for small moves. Samples unscanned before stay
/// unscanned.
AllowanceMap allowance_on_planes(const PartSamples& part, const Eigen::Isometry3d& T, const AllowanceMap& at);

/// Fills map.faces, map.all and map.min_face from map.allowance.
void summarise_allowance(const PartSamples& part, AllowanceMap& map);

/// A face's name for people: "face 3 (+X)" when its mean normal lies within 10 degrees of an axis of the
/// frame whose rotation in the mesh's coordinates is R_mesh_frame (the workpiece's datum frame), else
/// "face 3".
std::string face_name(const PartFace& face, const Eigen::Matrix3d& R_mesh_frame);

}  // namespace partloc
