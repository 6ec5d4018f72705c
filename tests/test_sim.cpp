// The virtual cell and scanner: shapes are closed solids, scans land on the surfaces with the requested
// noise, spacing, drop-out and outliers, every scenario scan sees what it must, and written jobs read back.
#include <gtest/gtest.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/io/PointCloudIO.h>
#include <open3d/io/TriangleMeshIO.h>
#include <open3d/t/geometry/RaycastingScene.h>
#include <open3d/t/geometry/TriangleMesh.h>
#include <open3d/utility/Logging.h>
#include <tbb/global_control.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <numeric>

#include "partloc/core/geometry.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/job_writer.hpp"
#include "partloc/sim/random.hpp"
#include "partloc/sim/scenario.hpp"

using namespace partloc;
using namespace partloc::sim;
namespace fs = std::filesystem;

namespace {

HeightField paper_like_fiducial() {
    HeightField b;
    b.x_edges = {0, 19.05, 38.1, 50.8};
    b.y_edges = {0, 15.875, 38.1};
    b.top = {31.75, 31.75, 22.225, 31.75, 12.7, 12.7};
    return b;
}

/// Random height fields of 1..4 x 1..4 cells with many distinct heights (saddles skipped).
std::vector<HeightField> random_height_fields(int count, std::uint64_t seed) {
    Rng rng(seed);
    std::vector<HeightField> out;
    while (static_cast<int>(out.size()) < count) {
        HeightField hf;
        const int nx = rng.integer(1, 4), ny = rng.integer(1, 4);
        double x = rng.uniform(-50, 50), y = rng.uniform(-50, 50);
        for (int i = 0; i <= nx; ++i, x += rng.uniform(3, 20)) hf.x_edges.push_back(x);
        for (int i = 0; i <= ny; ++i, y += rng.uniform(3, 20)) hf.y_edges.push_back(y);
        hf.bottom = rng.uniform(-20, 0);
        for (int i = 0; i < nx * ny; ++i) hf.top.push_back(hf.bottom + rng.integer(1, 5) * 4.0);
        try {
            check_height_field(hf);
        } catch (const std::invalid_argument&) {
            continue;
        }
        out.push_back(hf);
    }
    return out;
}

void expect_closed_outward(const Mesh& m, double expected_volume, double rel_tol) {
    EXPECT_TRUE(m.IsEdgeManifold(/*allow_boundary_edges=*/false));
    EXPECT_TRUE(m.IsVertexManifold());
    EXPECT_TRUE(m.IsWatertight());
    EXPECT_TRUE(m.IsOrientable());
    EXPECT_GT(signed_volume(m), 0.0) << "normals point inward";
    EXPECT_NEAR(signed_volume(m), expected_volume, rel_tol * expected_volume);
    ASSERT_TRUE(m.HasTriangleNormals());
    // Each stored normal agrees with its triangle's winding.
    for (std::size_t t = 0; t < m.triangles_.size(); ++t) {
        const auto& tri = m.triangles_[t];
        const Eigen::Vector3d n =
            (m.vertices_[tri(1)] - m.vertices_[tri(0)]).cross(m.vertices_[tri(2)] - m.vertices_[tri(0)]);
        ASSERT_GT(n.dot(m.triangle_normals_[t]), 0.0);
    }
}

/// A cell with one body: a plate whose top face (z = 0) is tilted by `tilt_deg` about the x axis, under a
/// scanner at the working distance looking straight down.
struct PlateRig {
    Cell cell;
    Eigen::Isometry3d T_machine_plate = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d T_machine_scanner = Eigen::Isometry3d::Identity();
};

PlateRig plate_rig(double tilt_deg, double working_distance) {
    PlateRig r;
    Body plate;
    plate.name = "plate";
    plate.mesh =
        make_box(Eigen::AlignedBox3d(Eigen::Vector3d(-400, -400, -20), Eigen::Vector3d(400, 400, 0)));
    r.T_machine_plate.linear() =
        Eigen::AngleAxisd(tilt_deg * M_PI / 180, Eigen::Vector3d::UnitX()).toRotationMatrix();
    plate.T_machine_body = r.T_machine_plate;
    r.cell.bodies.push_back(plate);
    r.T_machine_scanner = look_at({0, 0, working_distance}, {0, 0, 0}, Eigen::Vector3d::UnitY());
    return r;
}

/// Signed distances of the scan points to the plate's top plane.
std::vector<double> plate_residuals(const PlateRig& r, const SimulatedScan& s) {
    const Eigen::Isometry3d T = r.T_machine_plate.inverse() * r.T_machine_scanner;
    std::vector<double> d;
    for (const auto& p : s.points->points_) d.push_back((T * p).z());
    return d;
}

double mean(const std::vector<double>& v) { return std::accumulate(v.begin(), v.end(), 0.0) / v.size(); }
double stddev(const std::vector<double>& v) {
    const double m = mean(v);
    double s = 0;
    for (double x : v) s += (x - m) * (x - m);
    return std::sqrt(s / (v.size() - 1));
}

/// Scenario jobs are built once and shared by the tests below.
const SimulatedJob& paper(int test) {
    static std::map<int, SimulatedJob> cache;
    auto it = cache.find(test);
    if (it == cache.end()) it = cache.emplace(test, simulate_paper_test(test, 1)).first;
    return it->second;
}
const SimulatedJob& random_cell(std::uint64_t seed) {
    static std::map<std::uint64_t, SimulatedJob> cache;
    auto it = cache.find(seed);
    if (it == cache.end()) it = cache.emplace(seed, simulate_random_cell(seed)).first;
    return it->second;
}

fs::path fresh_dir(const std::string& name) {
    const fs::path dir =
        fs::temp_directory_path() / ("partloc_test_sim_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

}  // namespace

// ---------------------------------------------------------------------------------------------- shapes

TEST(Shapes, BoxAndCylinderAreClosedWithOutwardNormals) {
    expect_closed_outward(*make_box(Eigen::AlignedBox3d(Eigen::Vector3d(-1, 2, 3), Eigen::Vector3d(4, 9, 5))),
                          5 * 7 * 2, 1e-12);
    const int n = 40;
    const double r = 12, h = 30;
    expect_closed_outward(*make_cylinder(r, -10, 20, n), 0.5 * n * r * r * std::sin(2 * M_PI / n) * h, 1e-12);
}

TEST(Shapes, HeightFieldBlocksAreClosedWithTheirVolume) {
    auto fields = random_height_fields(60, 3);
    fields.push_back(paper_like_fiducial());
    for (const auto& hf : fields) {
        SCOPED_TRACE(::testing::Message() << hf.nx() << " x " << hf.ny() << " cells");
        const auto mesh = make_height_field_block(hf);
        expect_closed_outward(*mesh, volume(hf), 1e-9);
        // Walls only where neighbours differ: no two triangles overlap on the same plane from both sides.
        EXPECT_FALSE(mesh->IsSelfIntersecting());
    }
}

TEST(Shapes, HeightFieldRejectsCellsTouchingAlongAnEdgeOnly) {
    HeightField hf;
    hf.x_edges = {0, 10, 20};
    hf.y_edges = {0, 10, 20};
    hf.top = {10, 5, 5, 10};  // diagonal cells tall: the solid would touch itself along x = y = 10
    EXPECT_THROW(check_height_field(hf), std::invalid_argument);
    EXPECT_THROW(make_height_field_block(hf), std::invalid_argument);
    hf.top = {10, 10, 5, 10};
    EXPECT_NO_THROW(make_height_field_block(hf));
    hf.top = {10, 10, 0, 10};  // a top not above the bottom
    EXPECT_THROW(check_height_field(hf), std::invalid_argument);
}

TEST(Shapes, SymmetryCheckFindsTurnsAndCongruentFaces) {
    EXPECT_TRUE(has_no_symmetry(paper_like_fiducial()));
    HeightField hf;
    hf.x_edges = {0, 10, 20, 30};
    hf.y_edges = {0, 15};
    hf.top = {8, 8, 8};
    EXPECT_FALSE(has_no_symmetry(hf)) << "a box";
    hf.top = {8, 4, 8};
    EXPECT_FALSE(has_no_symmetry(hf)) << "turns onto itself by 180 degrees";
    hf.top = {8, 4, 6};
    EXPECT_TRUE(has_no_symmetry(hf));
    // An L-section bar whose two legs are equal maps onto itself by a half turn about the L's diagonal.
    hf.x_edges = {0, 10, 30};
    hf.top = {30, 10};
    EXPECT_FALSE(has_no_symmetry(hf));
    // Square footprint with a quarter-turn symmetry.
    hf.x_edges = {0, 10, 20, 30};
    hf.y_edges = {0, 10, 20, 30};
    hf.top = {5, 6, 5, 6, 9, 6, 5, 6, 5};
    EXPECT_FALSE(has_no_symmetry(hf));
    hf.top = {5, 7, 5, 6, 9, 6, 5, 6, 5};
    EXPECT_TRUE(has_no_symmetry(hf));
}

TEST(Shapes, CornerFacesLieOnTheBlockAndMeetAtTheDatum) {
    const HeightField b = paper_like_fiducial();
    ASSERT_TRUE(is_concave_corner(b, 1, 1));
    EXPECT_FALSE(is_concave_corner(b, 2, 1));
    EXPECT_FALSE(is_concave_corner(b, 0, 0));
    const Eigen::Isometry3d T = corner_frame(b, 1, 1);
    EXPECT_NEAR((T.translation() - Eigen::Vector3d(19.05, 15.875, 12.7)).norm(), 0, 1e-12);
    const auto faces = corner_faces(b, 1, 1);
    const auto mesh = make_height_field_block(b);
    const auto tags = classify_triangles(*mesh, {faces.begin(), faces.end()});
    for (int f = 0; f < 3; ++f) {
        EXPECT_NEAR((faces[f].normal() - Eigen::Vector3d::Unit(f)).norm(), 0, 1e-12) << "face " << f;
        EXPECT_TRUE(faces[f].contains(T.translation()));
        double area = 0;
        for (std::size_t t = 0; t < tags.size(); ++t)
            if (tags[t] == f + 1) {
                const auto& tri = mesh->triangles_[t];
                area += 0.5 * (mesh->vertices_[tri(1)] - mesh->vertices_[tri(0)])
                                  .cross(mesh->vertices_[tri(2)] - mesh->vertices_[tri(0)])
                                  .norm();
                EXPECT_GT(mesh->triangle_normals_[t].dot(faces[f].normal()), 0.999);
            }
        EXPECT_NEAR(area, faces[f].u.cross(faces[f].v).norm(), 1e-9) << "face " << f << " is on the surface";
    }
    EXPECT_THROW(corner_frame(b, 2, 1), std::invalid_argument);
}

// --------------------------------------------------------------------------------------------- scanner

TEST(Scanner, NoiseAlongTheLineOfSightHasTheRequestedSigma) {
    const PlateRig r = plate_rig(0, 430);
    const RayScene scene(r.cell, {});
    ScannerSettings s;
    s.field_width = s.field_height = 60;
    s.dropout = 0;
    s.outlier_fraction = 0;
    for (double sigma : {0.05, 0.13, 0.4}) {
        s.noise_sigma = sigma;
        const auto d = plate_residuals(r, scan(scene, r.T_machine_scanner, s));
        ASSERT_GT(d.size(), 20000u);
        // Rays within 4 degrees of the normal: the residual along z is the range noise.
        EXPECT_NEAR(stddev(d), sigma, 0.03 * sigma);
        EXPECT_NEAR(mean(d), 0.0, 0.05 * sigma);
    }
}

TEST(Scanner, PointSpacingAtTheWorkingDistanceIsAsRequested) {
    const PlateRig r = plate_rig(0, 430);
    const RayScene scene(r.cell, {});
    ScannerSettings s;
    s.field_width = s.field_height = 40;
    s.noise_sigma = 0;
    s.dropout = 0;
    s.outlier_fraction = 0;
    const auto sim = scan(scene, r.T_machine_scanner, s);
    open3d::geometry::KDTreeFlann tree(*sim.points);
    std::vector<double> nn;
    for (std::size_t i = 0; i < sim.points->points_.size(); i += 7) {
        std::vector<int> idx;
        std::vector<double> d2;
        tree.SearchKNN(sim.points->points_[i], 2, idx, d2);
        nn.push_back(std::sqrt(d2[1]));
    }
    std::nth_element(nn.begin(), nn.begin() + nn.size() / 2, nn.end());
    EXPECT_NEAR(nn[nn.size() / 2], s.point_spacing, 0.005 * s.point_spacing);
    // The paper's density: 4,400 points per square inch (Table 1).
    const double per_square_inch =
        sim.points->points_.size() / (s.field_width * s.field_height) * 25.4 * 25.4;
    EXPECT_NEAR(per_square_inch, 4400, 0.03 * 4400);
    // Twice the distance, twice the spacing: the ray grid is angular.
    const PlateRig far = plate_rig(0, 600);
    const RayScene far_scene(far.cell, {});
    const auto far_sim = scan(far_scene, far.T_machine_scanner, s);
    const auto& P = far_sim.points->points_;
    const int nu = static_cast<int>(std::floor(s.field_width / s.point_spacing)) + 1;
    EXPECT_NEAR((P[1] - P[0]).norm(), s.point_spacing * 600 / 430, 0.002);
    EXPECT_NEAR((P[nu] - P[0]).norm(), s.point_spacing * 600 / 430, 0.002);
}

TEST(Scanner, DropOutGrowsTowardGrazingIncidenceAsRequested) {
    ScannerSettings s;
    s.field_width = s.field_height = 40;  // within 3 degrees of the central ray
    s.dropout = 0.1;
    s.outlier_fraction = 0;
    for (double tilt : {0.0, 45.0, 60.0, 85.0}) {
        const PlateRig r = plate_rig(tilt, 430);
        const RayScene scene(r.cell, {});
        const auto sim = scan(scene, r.T_machine_scanner, s);
        const double lost = static_cast<double>(sim.dropped) / (sim.rays - sim.missed);
        const double expected =
            tilt >= s.max_incidence_deg
                ? 1.0
                : s.dropout + (1 - s.dropout) * std::pow(tilt / s.max_incidence_deg, s.dropout_exponent);
        SCOPED_TRACE(::testing::Message() << "tilt " << tilt);
        EXPECT_EQ(sim.points->points_.size() + sim.dropped + sim.missed, sim.rays);
        if (tilt >= s.max_incidence_deg) {  // nothing returns; far rays may also leave the depth of field
            EXPECT_EQ(sim.points->points_.size(), 0u);
            continue;
        }
        EXPECT_EQ(sim.missed, 0u);
        // The edge rays meet the plate 3 degrees either side of `tilt`: allow for it and for sampling.
        EXPECT_NEAR(lost, expected, 0.012 + 0.3 * (expected - s.dropout));
    }
}

TEST(Scanner, OutliersAppearAtTheRequestedRateAndAreFarOffTheSurface) {
    const PlateRig r = plate_rig(0, 430);
    const RayScene scene(r.cell, {});
    ScannerSettings s;
    s.field_width = s.field_height = 60;
    s.dropout = 0;
    s.outlier_fraction = 0.05;
    const auto sim = scan(scene, r.T_machine_scanner, s);
    const auto d = plate_residuals(r, sim);
    std::size_t flagged = 0, far = 0, mismatch = 0;
    for (std::size_t i = 0; i < d.size(); ++i) {
        const bool off = std::abs(d[i]) > 1.5;  // 11 sigma: only outliers
        far += off;
        flagged += sim.outlier[i];
        mismatch += off != static_cast<bool>(sim.outlier[i]);
    }
    const double n = static_cast<double>(d.size());
    EXPECT_NEAR(far / n, s.outlier_fraction, 4 * std::sqrt(s.outlier_fraction / n) + 1e-3);
    EXPECT_EQ(flagged, far);
    EXPECT_EQ(mismatch, 0u);
}

TEST(Scanner, CellScanLiesOnTheSurfacesWhereTruthPutsIt) {
    // Independent check: Open3D's closest-point query (not Embree's rays) on the cell's bodies placed at the
    // scan's axis values, with the scan moved by the true T_machine_scan.
    const SimulatedJob& sj = paper(3);
    const double sigma = ScannerSettings{}.noise_sigma;
    for (std::size_t k : {0u, 3u, 5u}) {
        const ScanTruth& t = sj.truth.scans[k];
        open3d::t::geometry::RaycastingScene distances;
        for (const auto& body : sj.cell.bodies) {
            auto m = std::make_shared<Mesh>(*body.mesh);
            m->Transform(sj.cell.T_machine_body(body, t.axes).matrix());
            distances.AddTriangles(open3d::t::geometry::TriangleMesh::FromLegacy(*m));
        }
        const SimulatedScan& s = sj.scans[k];
        std::vector<float> q;
        std::vector<std::uint8_t> is_outlier;
        for (std::size_t i = 0; i < s.points->points_.size(); i += 5) {
            const Eigen::Vector3d p = t.T_machine_scan * s.points->points_[i];
            q.insert(q.end(),
                     {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())});
            is_outlier.push_back(s.outlier[i]);
        }
        const auto n = static_cast<int64_t>(is_outlier.size());
        const auto d = distances.ComputeDistance(open3d::core::Tensor(q, {n, 3}, open3d::core::Float32));
        const float* dist = d.GetDataPtr<float>();
        double sum2 = 0;
        std::size_t inliers = 0, within4 = 0;
        for (int64_t i = 0; i < n; ++i) {
            if (is_outlier[i]) continue;
            ++inliers;
            sum2 += dist[i] * dist[i];
            within4 += dist[i] < 4 * sigma;
        }
        const double rms = std::sqrt(sum2 / inliers);
        SCOPED_TRACE(::testing::Message() << t.file << ": rms " << rms << " mm");
        ASSERT_GT(inliers, 20000u);
        // The distance to the surface is the range noise times the cosine of the incidence (at most sigma).
        EXPECT_LT(rms, 1.02 * sigma);
        EXPECT_GT(rms, 0.5 * sigma);
        EXPECT_GT(static_cast<double>(within4) / inliers, 0.9995);
    }
}

TEST(Scanner, SameSeedSameScanOtherSeedOtherScanAnyThreadCount) {
    const PlateRig r = plate_rig(30, 430);
    const RayScene scene(r.cell, {});
    ScannerSettings s;
    s.field_width = s.field_height = 50;
    const auto a = scan(scene, r.T_machine_scanner, s);
    SimulatedScan b;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        b = scan(scene, r.T_machine_scanner, s);
    }
    ASSERT_EQ(a.points->points_.size(), b.points->points_.size());
    EXPECT_TRUE(std::equal(a.points->points_.begin(), a.points->points_.end(), b.points->points_.begin()));
    EXPECT_EQ(a.outlier, b.outlier);
    s.seed = 2;
    const auto c = scan(scene, r.T_machine_scanner, s);
    const std::size_t n = std::min(a.points->points_.size(), c.points->points_.size());
    std::size_t same = 0;
    for (std::size_t i = 0; i < n; ++i) same += a.points->points_[i] == c.points->points_[i];
    EXPECT_LT(same, n / 100);
}

// ------------------------------------------------------------------------------------------- scenarios

TEST(Scenario, PaperTestsPutTheWorkpieceAtTable4AndEveryScanSeesDatumAndAFiducial) {
    const ScenarioOptions o;
    for (int test = 1; test <= 5; ++test) {
        const SimulatedJob& sj = paper(test);
        SCOPED_TRACE(sj.truth.scenario);
        const PaperPose m = paper_measured_pose(test);
        EXPECT_NEAR((sj.truth.T_machine_workpiece.translation() - m.origin).norm(), 0, 1e-9);
        EXPECT_NEAR((euler_xyz_deg(sj.truth.T_machine_workpiece.linear()) - m.euler_deg).norm(), 0, 1e-9);
        EXPECT_NEAR(
            (sj.job.workpiece.T_machine_workpiece.translation() - Eigen::Vector3d(-76.2, -12.7, 20.32))
                .norm(),
            0, 1e-9);
        EXPECT_TRUE(sj.job.workpiece.T_machine_workpiece.linear().isIdentity(1e-12));
        ASSERT_EQ(sj.job.fiducials.size(), 2u);
        for (int f = 0; f < 3; ++f)
            EXPECT_GE(required_face_points(o, sj.truth, f), 600u) << "a real requirement";
        ASSERT_EQ(sj.job.scans.size(), 6u);
        ASSERT_EQ(sj.truth.scans.size(), 6u);
        const double a_values[6] = {0, 0, 45, 45, 90, 90};
        for (std::size_t k = 0; k < 6; ++k) {
            const ScanTruth& t = sj.truth.scans[k];
            SCOPED_TRACE(t.file);
            EXPECT_EQ(sj.job.scans[k].file, t.file);
            EXPECT_DOUBLE_EQ(sj.job.scans[k].axes.at("A"), a_values[k]);
            EXPECT_EQ(sj.job.scans[k].points->points_.size(), t.points);
            EXPECT_GT(t.points, 100000u);
            EXPECT_LT(t.points, 400000u);
            for (int f = 0; f < 3; ++f)
                EXPECT_GE(t.reference_points[f], required_face_points(o, sj.truth, f)) << "datum face " << f;
            std::size_t best = 0;
            for (const auto& [name, n] : t.fiducial_points) best = std::max(best, n);
            EXPECT_GE(best, o.min_fiducial_points);
        }
    }
}

TEST(Scenario, RandomCellsAreUnseenShapesAndEveryScanSeesDatumAndAFiducial) {
    const ScenarioOptions o;
    std::vector<double> volumes;
    for (std::uint64_t seed : {1, 2, 3, 4}) {
        const SimulatedJob& sj = random_cell(seed);
        SCOPED_TRACE(::testing::Message() << "seed " << seed);
        ASSERT_GE(sj.job.fiducials.size(), 2u);
        ASSERT_LE(sj.job.fiducials.size(), 3u);
        ASSERT_EQ(sj.truth.scans.size(), 6u);
        // Misplaced by a few mm and degrees.
        const PoseError off = pose_error(sj.truth.T_machine_workpiece, sj.truth.T_machine_workpiece_nominal);
        EXPECT_GT(off.translation + off.rotation_deg, 0.1);
        EXPECT_LT(off.translation, 5.0);
        EXPECT_LT(off.rotation_deg, 7.0);
        for (const auto& t : sj.truth.scans) {
            SCOPED_TRACE(t.file);
            for (int f = 0; f < 3; ++f)
                EXPECT_GE(t.reference_points[f], required_face_points(o, sj.truth, f)) << "datum face " << f;
            std::size_t best = 0;
            for (const auto& [name, n] : t.fiducial_points) best = std::max(best, n);
            EXPECT_GE(best, o.min_fiducial_points);
        }
        for (const auto& f : sj.job.fiducials) volumes.push_back(signed_volume(*f.model.mesh));
    }
    std::sort(volumes.begin(), volumes.end());
    EXPECT_EQ(std::adjacent_find(volumes.begin(), volumes.end()), volumes.end()) << "fiducials repeat";
}

TEST(Scenario, BodiesSitWhereTheCellSays) {
    const SimulatedJob& sj = random_cell(2);
    const Cell& cell = sj.cell;
    const FixtureLayout layout;
    // Fiducials: bottom on the pallet's top, unique shapes, fixed under A; their job pose is the true pose.
    for (const auto& f : sj.job.fiducials) {
        const int b = cell.find(f.name);
        ASSERT_GE(b, 0);
        const Body& body = cell.bodies[b];
        EXPECT_EQ(body.kind, BodyKind::Fiducial);
        EXPECT_TRUE(body.moves_with.empty());
        EXPECT_TRUE(f.T_machine_fiducial.isApprox(body.T_machine_body, 1e-12));
        double zmin = 1e9;
        for (const auto& v : body.mesh->vertices_) zmin = std::min(zmin, (body.T_machine_body * v).z());
        EXPECT_NEAR(zmin, layout.pallet_top, 1e-9);
        expect_closed_outward(*body.mesh, signed_volume(*body.mesh), 1e-12);
        EXPECT_TRUE(cell.T_machine_body(body, {{"A", 90}}).isApprox(body.T_machine_body, 1e-12));
    }
    // Workpiece: body_true = T_true * T_nominal^-1 * body_nominal, turning with A about the X axis.
    const Body& wp = cell.bodies[cell.find("workpiece")];
    const Eigen::Isometry3d& N = sj.truth.T_machine_workpiece_nominal;
    const Eigen::Isometry3d& T = sj.truth.T_machine_workpiece;
    EXPECT_TRUE((wp.T_machine_body * N).isApprox(T, 1e-12));
    const Eigen::Isometry3d A45 = rotation_about_line(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitX(), 45);
    EXPECT_TRUE((cell.T_machine_body(wp, {{"A", 45}}) * N).isApprox(A45 * T, 1e-12));
    // The reference surfaces in the job are the three datum faces at the nominal place.
    const auto& ref = *sj.job.workpiece.reference_surfaces.mesh;
    EXPECT_EQ(ref.triangles_.size(), 6u);
    for (const auto& v : ref.vertices_) {
        const Eigen::Vector3d local = N.inverse() * v;
        EXPECT_GE(local.minCoeff(), -1e-9);
        EXPECT_NEAR(local.cwiseAbs().minCoeff(), 0, 1e-9) << "a vertex off the datum planes";
    }
    ASSERT_TRUE(sj.job.workpiece.region);
    EXPECT_TRUE(sj.job.workpiece.region->contains(N.translation()));
    EXPECT_TRUE(sj.job.workpiece.region->contains(T.translation()));
    ASSERT_TRUE(sj.job.workpiece.final_part);
    EXPECT_TRUE(sj.job.workpiece.final_part->mesh->IsWatertight());
}

TEST(Scenario, SameSeedSameJobOtherSeedOtherViews) {
    ScenarioOptions o;
    o.a_values = {45};
    o.scans_per_position = 1;
    const SimulatedJob a = simulate_paper_test(4, 9, o);
    const SimulatedJob b = simulate_paper_test(4, 9, o);
    const SimulatedJob c = simulate_paper_test(4, 10, o);
    ASSERT_EQ(a.job.scans.size(), 1u);
    EXPECT_TRUE(a.truth.scans[0].T_machine_scan.isApprox(b.truth.scans[0].T_machine_scan, 0));
    ASSERT_EQ(a.job.scans[0].points->points_.size(), b.job.scans[0].points->points_.size());
    EXPECT_TRUE(std::equal(a.job.scans[0].points->points_.begin(), a.job.scans[0].points->points_.end(),
                           b.job.scans[0].points->points_.begin()));
    EXPECT_GT(pose_error(a.truth.scans[0].T_machine_scan, c.truth.scans[0].T_machine_scan).translation, 1.0);
    // Random cells: the seed chooses the shapes.
    EXPECT_NE(signed_volume(*random_cell(1).job.fiducials[0].model.mesh),
              signed_volume(*random_cell(2).job.fiducials[0].model.mesh));
}

// ------------------------------------------------------------------------------------------ job writer

TEST(JobWriter, WrittenJobReadsBackAsWritten) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const SimulatedJob& sj = random_cell(3);
    const fs::path dir = fresh_dir("roundtrip");
    io::write_job(dir, sj.job);
    io::write_truth(dir / "truth.json", sj.truth);

    // Files, read back with Open3D.
    for (std::size_t k = 0; k < sj.job.scans.size(); ++k) {
        open3d::geometry::PointCloud pc;
        ASSERT_TRUE(open3d::io::ReadPointCloud((dir / sj.job.scans[k].file).string(), pc));
        const auto& P = sj.job.scans[k].points->points_;
        ASSERT_EQ(pc.points_.size(), P.size());
        for (std::size_t i = 0; i < P.size(); i += 97) EXPECT_LT((pc.points_[i] - P[i]).norm(), 1e-4);
    }
    for (const auto& f : sj.job.fiducials) {
        open3d::geometry::TriangleMesh m;
        ASSERT_TRUE(open3d::io::ReadTriangleMesh((dir / f.model.file).string(), m));
        EXPECT_EQ(m.triangles_.size(), f.model.mesh->triangles_.size());
        EXPECT_NEAR(signed_volume(m), signed_volume(*f.model.mesh),
                    1e-6 * signed_volume(*f.model.mesh));  // float STL
    }
    EXPECT_TRUE(fs::exists(dir / "models/workpiece_reference.stl"));
    EXPECT_TRUE(fs::exists(dir / "models/final_part.stl"));

    // job.yaml, as SPEC spells it.
    const YAML::Node y = YAML::LoadFile((dir / "job.yaml").string());
    EXPECT_EQ(y["units"].as<std::string>(), "mm");
    EXPECT_EQ(y["machine"]["axes"][0]["name"].as<std::string>(), "A");
    EXPECT_EQ(y["machine"]["axes"][0]["type"].as<std::string>(), "rotary");
    EXPECT_EQ(y["fiducials"].size(), sj.job.fiducials.size());
    EXPECT_TRUE(y["fiducials"][0]["model"].IsScalar());
    EXPECT_EQ(y["workpiece"]["moves_with"][0].as<std::string>(), "A");
    EXPECT_EQ(y["scans"].size(), 6u);
    EXPECT_DOUBLE_EQ(y["scans"][5]["axes"]["A"].as<double>(), 90.0);
    EXPECT_DOUBLE_EQ(y["scanner"]["noise"].as<double>(), 0.13);

    // Through the I/O layer's reader, as `partloc run` reads it.
    const Job job = io::load_job(dir / "job.yaml");
    ASSERT_EQ(job.fiducials.size(), sj.job.fiducials.size());
    for (std::size_t i = 0; i < job.fiducials.size(); ++i) {
        EXPECT_EQ(job.fiducials[i].name, sj.job.fiducials[i].name);
        EXPECT_LT(pose_error(job.fiducials[i].T_machine_fiducial, sj.job.fiducials[i].T_machine_fiducial)
                      .translation,
                  1e-9);
        EXPECT_LT(pose_error(job.fiducials[i].T_machine_fiducial, sj.job.fiducials[i].T_machine_fiducial)
                      .rotation_deg,
                  1e-6);
    }
    EXPECT_LT(pose_error(job.workpiece.T_machine_workpiece, sj.job.workpiece.T_machine_workpiece).translation,
              1e-9);
    ASSERT_TRUE(job.workpiece.region);
    EXPECT_TRUE(job.workpiece.region->isApprox(*sj.job.workpiece.region, 1e-12));
    ASSERT_EQ(job.scans.size(), sj.job.scans.size());
    for (std::size_t k = 0; k < job.scans.size(); ++k) {
        EXPECT_EQ(job.scans[k].points->points_.size(), sj.job.scans[k].points->points_.size());
        EXPECT_DOUBLE_EQ(job.scans[k].axes.at("A"), sj.job.scans[k].axes.at("A"));
    }
    ASSERT_EQ(job.machine.axes.size(), 1u);
    EXPECT_EQ(job.machine.axes[0].type, AxisType::Rotary);

    // truth.json.
    std::ifstream in(dir / "truth.json");
    const auto j = nlohmann::json::parse(in);
    EXPECT_EQ(j["scenario"], "random_cell");
    EXPECT_EQ(j["scans"].size(), 6u);
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
            EXPECT_DOUBLE_EQ(j["workpiece"]["T_machine_workpiece"][r][c].get<double>(),
                             sj.truth.T_machine_workpiece.matrix()(r, c));
    EXPECT_EQ(j["scans"][0]["points"].get<std::size_t>(), sj.truth.scans[0].points);
    fs::remove_all(dir);
}

TEST(JobWriter, RefusesFilesOutsideTheJobFolder) {
    Job job;
    job.workpiece.reference_surfaces.file = "../escape.stl";
    job.workpiece.reference_surfaces.mesh =
        make_box(Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()));
    const fs::path dir = fresh_dir("escape");
    EXPECT_THROW(io::write_job(dir, job), std::invalid_argument);
    job.workpiece.reference_surfaces.file = "models/ref.stl";
    job.workpiece.reference_surfaces.mesh = nullptr;
    EXPECT_THROW(io::write_job(dir, job), std::invalid_argument);
    EXPECT_FALSE(fs::exists(dir / "job.yaml"));
    fs::remove_all(dir);
}

TEST(Cli, SimulateWritesAJobThatRunAccepts) {
    const fs::path dir = fresh_dir("cli");
    const std::string cmd = std::string(PARTLOC_EXE) + " simulate --out " + (dir / "job").string() +
                            " --seed 5 > " + (dir / "log.txt").string() + " 2>&1";
    ASSERT_EQ(std::system(cmd.c_str()), 0);
    EXPECT_TRUE(fs::exists(dir / "job/job.yaml"));
    EXPECT_TRUE(fs::exists(dir / "job/truth.json"));
    EXPECT_TRUE(fs::exists(dir / "job/scans/scan_06.ply"));
    const Job job = io::load_job(dir / "job/job.yaml");
    EXPECT_EQ(job.scans.size(), 6u);
    fs::remove_all(dir);
}
