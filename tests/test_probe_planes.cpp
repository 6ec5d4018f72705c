// Poses from probed points on three planes (issue 4, paper §3.2 and §4): the frame fit against known poses,
// with and without probing noise, on the sim's own fiducial and workpiece corners (the convention must match
// how the models are built), through the job loader (mm and inch jobs), and every kind of bad probing.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "partloc/core/geometry.hpp"
#include "partloc/core/probe_planes.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/result_io.hpp"
#include "partloc/sim/shapes.hpp"
#include "test_note.hpp"
#include "test_util.hpp"

using namespace partloc;
using namespace partloc::test;
namespace fs = std::filesystem;

namespace {

using Planes = std::array<std::vector<Eigen::Vector3d>, 3>;

/// Probe points on the three faces of a concave corner at the origin of a frame (faces x = 0, y = 0, z = 0,
/// the material on their far sides, the probe coming from the octant x, y, z > 0), moved by T_machine_frame,
/// with Gaussian noise of `sigma` along each face's normal. `n` points per face over [1, size] x [1, size].
Planes probe_corner(const Eigen::Isometry3d& T, int n, double size, double sigma, std::mt19937& rng) {
    // As a probing routine places them: the first three spread over the face (a triangle, jittered), the
    // rest anywhere on it.
    std::uniform_real_distribution<double> u(1.0, size), jitter(-0.1 * size, 0.1 * size);
    std::normal_distribution<double> noise(0.0, sigma);
    const double layout[3][2] = {{0.2, 0.2}, {0.8, 0.3}, {0.4, 0.8}};
    Planes planes;
    for (int axis = 0; axis < 3; ++axis)
        for (int i = 0; i < n; ++i) {
            Eigen::Vector3d p(u(rng), u(rng), u(rng));
            if (i < 3) {
                p[(axis + 1) % 3] = layout[i][0] * size + jitter(rng);
                p[(axis + 2) % 3] = layout[i][1] * size + jitter(rng);
            }
            p[axis] = noise(rng);
            planes[axis].push_back(T * p);
        }
    return planes;
}

/// Poses compared element by element (pose_error's acos resolves no better than 1e-6 degrees).
void expect_same_pose(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double tol) {
    EXPECT_LT((a.translation() - b.translation()).norm(), tol);
    EXPECT_LT((a.linear() - b.linear()).norm(), tol);
}

Eigen::Isometry3d random_pose(std::mt19937& rng) {
    std::uniform_real_distribution<double> t(-200, 200), a(-180, 180), b(-89, 89);
    return pose_from_origin_euler({t(rng), t(rng), t(rng)}, {a(rng), b(rng), a(rng)});
}

}  // namespace

TEST(ProbePlanes, ExactPointsGiveTheExactFrame) {
    std::mt19937 rng(1);
    for (int trial = 0; trial < 50; ++trial) {
        const Eigen::Isometry3d T = random_pose(rng);
        const ProbedFrame f =
            frame_from_probe_planes(probe_corner(T, 3, 25.0, 0.0, rng));  // the paper: 3 each
        ASSERT_TRUE(f.valid) << f.reason;
        expect_same_pose(f.T, T, 1e-10);
        for (const auto& p : f.planes) EXPECT_LT(p.rms, 1e-10);
        EXPECT_LT(f.nonorthogonality_deg, 1e-9);
    }
}

TEST(ProbePlanes, ProbingNoiseOfFiveMicronsMovesTheFrameLittle) {
    // 8 points per face over 40 mm with 0.005 mm noise: a normal is good to about
    // 0.005 / (39 / sqrt(12) * sqrt(8)) rad = 0.009 degrees; the corner lies at the edge of the points, so a
    // tilt moves it by up to 30 mm times that, and each plane's offset by 0.005 / sqrt(8): 0.005 mm or so.
    std::mt19937 rng(2);
    double sum_t2 = 0, sum_r2 = 0, worst_t = 0, worst_r = 0, mean_rms = 0;
    const int trials = 300;
    for (int trial = 0; trial < trials; ++trial) {
        const Eigen::Isometry3d T = random_pose(rng);
        const ProbedFrame f = frame_from_probe_planes(probe_corner(T, 8, 40.0, 0.005, rng));
        ASSERT_TRUE(f.valid) << f.reason;
        const PoseError e = pose_error(f.T, T);
        sum_t2 += e.translation * e.translation;
        sum_r2 += e.rotation_deg * e.rotation_deg;
        worst_t = std::max(worst_t, e.translation);
        worst_r = std::max(worst_r, e.rotation_deg);
        for (const auto& p : f.planes) mean_rms += p.rms / (3.0 * trials);
    }
    const double rms_t = std::sqrt(sum_t2 / trials), rms_r = std::sqrt(sum_r2 / trials);
    partloc::test::note(
        "probe noise 0.005 mm, 8 points per plane, %d poses: origin error rms %.5f worst %.5f mm, "
        "rotation error rms %.5f worst %.5f deg, mean plane rms %.5f mm\n",
        trials, rms_t, worst_t, rms_r, worst_r, mean_rms);
    EXPECT_LT(rms_t, 0.015);
    EXPECT_LT(rms_r, 0.02);
    EXPECT_LT(worst_t, 0.05);
    EXPECT_LT(worst_r, 0.06);
    EXPECT_GT(rms_r, 0.003);  // the noise does reach the result: this is no exact-points test
    EXPECT_NEAR(mean_rms, 0.005 * std::sqrt(5.0 / 8.0), 0.0008);  // 8 points, 3 parameters of the plane
}

TEST(ProbePlanes, ConventionMatchesTheSimsModelFrames) {
    // The sim builds a fiducial model (and the workpiece datum) at corner_frame: the three corner faces,
    // ordered +x wall, +y wall, floor. Probing those faces of the block where it stands must give back the
    // pose the model is placed at.
    std::mt19937 rng(3);
    sim::HeightField fid;  // a step block, its concave corner at cell (1, 1)
    fid.x_edges = {0.0, 19.05, 38.1, 50.8};
    fid.y_edges = {0.0, 15.875, 38.1};
    fid.top = {31.75, 31.75, 22.225, 31.75, 12.7, 12.7};
    sim::HeightField bar;  // the paper's workpiece: a step milled on a square bar
    bar.x_edges = {-160.0, -76.2, -20.0, 30.0};
    bar.y_edges = {-31.75, -12.7, 31.75};
    bar.bottom = -31.75;
    bar.top = {31.75, 31.75, 31.75, 31.75, 20.32, 31.75};
    for (const sim::HeightField* hf : {&fid, &bar}) {
        ASSERT_TRUE(sim::is_concave_corner(*hf, 1, 1));
        const Eigen::Isometry3d T_block_frame = sim::corner_frame(*hf, 1, 1);
        const auto faces = sim::corner_faces(*hf, 1, 1);
        for (int trial = 0; trial < 10; ++trial) {
            const Eigen::Isometry3d T_machine_frame = random_pose(rng);
            const Eigen::Isometry3d T_machine_block = T_machine_frame * T_block_frame.inverse();
            Planes planes;
            std::uniform_real_distribution<double> s(0.05, 0.95);
            for (int k = 0; k < 3; ++k)
                for (int i = 0; i < 4; ++i)
                    planes[k].push_back(T_machine_block *
                                        (faces[k].origin + s(rng) * faces[k].u + s(rng) * faces[k].v));
            const ProbedFrame f = frame_from_probe_planes(planes);
            ASSERT_TRUE(f.valid) << f.reason;
            expect_same_pose(f.T, T_machine_frame, 1e-10);
        }
    }
}

TEST(ProbePlanes, BadProbingIsAReasonNamingThePlane) {
    std::mt19937 rng(4);
    const Eigen::Isometry3d T = random_pose(rng);
    const Planes good = probe_corner(T, 5, 30.0, 0.0, rng);
    const auto expect_reason = [](const Planes& p, int plane, const std::string& phrase) {
        const ProbedFrame f = frame_from_probe_planes(p);
        EXPECT_FALSE(f.valid);
        EXPECT_EQ(f.plane, plane) << f.reason;
        EXPECT_NE(f.reason.find(phrase), std::string::npos) << f.reason;
    };
    Planes p = good;
    p[1].resize(2);
    expect_reason(p, 1, "needs at least 3 points, found 2");
    p = good;
    for (int i = 0; i < 5; ++i) p[2][i] = T * Eigen::Vector3d(2.0 + 5 * i, 2.0 + 5 * i, 0.0);  // along a line
    expect_reason(p, 2, "collinear");
    p = good;
    p[0][3] = p[0][3] + T.linear() * Eigen::Vector3d(5.0, 0, 0);  // a point 5 mm off its plane
    expect_reason(p, 0, "not on one plane");
    p = good;
    std::swap(p[0], p[1]);  // given in the order y, x, z
    expect_reason(p, -1, "left-handed");
    p = good;
    for (auto& q : p[2]) {  // the floor turned to 17 degrees from the y = 0 wall
        const Eigen::Vector3d l = T.inverse() * q;
        q = T * Eigen::Vector3d(l.x(), 1.0 + 0.3 * l.y(), 3.0 + l.y());
    }
    expect_reason(p, -1, "near-parallel");
    p = good;
    for (auto& q : p[2]) {  // the floor tilted 30 degrees: not a square corner
        const Eigen::Vector3d l = T.inverse() * q;
        q = T * Eigen::Vector3d(l.x(), l.y(), -std::tan(30 * M_PI / 180) * l.x());
    }
    expect_reason(p, -1, "from mutually perpendicular");
    p = good;
    for (auto& q : p[2]) {  // the floor probed on the far side of the x = 0 wall
        const Eigen::Vector3d l = T.inverse() * q;
        q = T * Eigen::Vector3d(l.x() - 31.0, l.y(), 0.0);
    }
    expect_reason(p, 0, "both sides");
}

// ---------------------------------------------------------------------------------------------------------
// Through the job file

namespace {

// A temporary folder holding a model and a scan, for the jobs these tests write.
struct Folder : TempFolder {
    Folder() : TempFolder("partloc_test_probe") {
        write("model.xyz", "0 0 0\n10 0 0\n0 10 0\n0 0 10\n");
        write("scan.xyz", "0 0 0\n1 0 0\n0 1 0\n");
    }
};

std::string yaml_points(const std::vector<Eigen::Vector3d>& pts, double scale) {
    std::ostringstream s;
    s.precision(12);
    s << "[";
    for (std::size_t i = 0; i < pts.size(); ++i)
        s << (i ? ", " : "") << "[" << pts[i].x() * scale << ", " << pts[i].y() * scale << ", "
          << pts[i].z() * scale << "]";
    s << "]";
    return s.str();
}

std::string yaml_planes(const Planes& p, double scale = 1.0) {
    return "{probe_planes: [" + yaml_points(p[0], scale) + ", " + yaml_points(p[1], scale) + ", " +
           yaml_points(p[2], scale) + "]}";
}

std::string job_text(const std::string& units, const std::string& pose_a, const std::string& datum,
                     const std::string& extra_b = "") {
    return "units: " + units +
           "\nfiducials:\n"
           "  - {name: A, model: model.xyz, pose: " +
           pose_a +
           "}\n"
           "  - {name: B, model: model.xyz, pose: {origin: [1, 2, 3]}" +
           extra_b +
           "}\n"
           "workpiece:\n  reference_surfaces: model.xyz\n  datum: " +
           datum + "\nscans: [scan.xyz]\n";
}

}  // namespace

TEST(ProbePlanesJob, FiducialAndDatumPosesFromProbedPoints) {
    Folder f;
    std::mt19937 rng(5);
    const Eigen::Isometry3d T_a = pose_from_origin_euler({60, -95, -40}, {1.5, -0.7, 93});
    const Eigen::Isometry3d T_w = pose_from_origin_euler({-76.2, -12.7, 20.32}, {-6.8, 0.1, 0.2});
    const Planes pa = probe_corner(T_a, 10, 40.0, 0.005, rng);
    const Planes pw = probe_corner(T_w, 10, 40.0, 0.005, rng);
    for (const char* units : {"mm", "in"}) {
        SCOPED_TRACE(units);
        const double scale =
            std::string(units) == "in" ? 1.0 / 25.4 : 1.0;  // points written in the job's units
        const Job job = io::load_job(
            f.write("job.yaml", job_text(units, yaml_planes(pa, scale), yaml_planes(pw, scale))));
        const auto back = [&](const Eigen::Isometry3d& T) {  // to mm
            Eigen::Isometry3d M = T;
            M.translation() /= scale;
            return M;
        };
        const PoseError ea = pose_error(back(job.fiducials[0].T_machine_fiducial), T_a);
        const PoseError ew = pose_error(back(job.workpiece.T_machine_workpiece), T_w);
        partloc::test::note(
            "%s job: fiducial A from probe_planes off by %.5f mm, %.5f deg; datum by %.5f mm, %.5f deg\n",
            units, ea.translation, ea.rotation_deg, ew.translation, ew.rotation_deg);
        EXPECT_LT(ea.translation, 0.03);
        EXPECT_LT(ea.rotation_deg, 0.04);
        EXPECT_LT(ew.translation, 0.03);
        EXPECT_LT(ew.rotation_deg, 0.04);
        // The same points through the core fit: the loader adds nothing and loses nothing (but the units).
        const ProbedFrame direct = frame_from_probe_planes(pa);
        expect_same_pose(back(job.fiducials[0].T_machine_fiducial), direct.T, 1e-8);
        ASSERT_EQ(job.probed_poses.size(), 2u);
        EXPECT_EQ(job.probed_poses[0].field, "fiducials[0].pose");
        EXPECT_EQ(job.probed_poses[1].field, "workpiece.datum");
        for (const auto& p : job.probed_poses[0].frame.planes) {
            EXPECT_EQ(p.points, 10u);
            EXPECT_GT(p.rms / scale, 0.001);
            EXPECT_LT(p.rms / scale, 0.01);
        }
        // pose_sigma: 0.005 mm in the job's units when not given.
        EXPECT_NEAR(job.fiducials[0].pose_sigma, 0.005 * scale, 1e-15);
        EXPECT_NEAR(job.fiducials[1].pose_sigma, 0.005 * scale, 1e-15);

        // result.json reports each probed pose with its planes' residuals.
        const auto j = nlohmann::json::parse(io::result_json(job, JobResult{}));
        ASSERT_EQ(j["probed_poses"].size(), 2u);
        EXPECT_EQ(j["probed_poses"][1]["field"], "workpiece.datum");
        EXPECT_EQ(j["probed_poses"][0]["planes"].size(), 3u);
        EXPECT_NEAR(j["probed_poses"][0]["planes"][2]["rms"].get<double>(),
                    job.probed_poses[0].frame.planes[2].rms, 1e-9);
    }
    const Job given = io::load_job(
        f.write("job.yaml", job_text("mm", yaml_planes(pa), "{origin: [0, 0, 0]}", ", pose_sigma: 0.02")));
    EXPECT_DOUBLE_EQ(given.fiducials[1].pose_sigma, 0.02);
    EXPECT_EQ(given.probed_poses.size(), 1u);
}

TEST(ProbePlanesJob, BadProbingIsOneLineNamingTheField) {
    Folder f;
    std::mt19937 rng(6);
    const Eigen::Isometry3d T = pose_from_origin_euler({10, 20, 30}, {0, 0, 30});
    const Planes good = probe_corner(T, 6, 30.0, 0.0, rng);
    const std::string datum = "{origin: [0, 0, 0]}";
    Planes p = good;
    p[1].resize(2);
    expect_job_error(f.write("job.yaml", job_text("mm", yaml_planes(p), datum)),
                     "fiducials[0].pose.probe_planes[1]: needs at least 3 points, found 2 (line 3)");
    p = good;
    std::swap(p[0], p[2]);
    expect_job_error(f.write("job.yaml", job_text("mm", yaml_planes(p), datum)),
                     "fiducials[0].pose.probe_planes: the planes, in this order, make a left-handed frame");
    p = good;
    p[2][4] += Eigen::Vector3d(0, 0, 5);
    expect_job_error(f.write("job.yaml", job_text("mm", datum, yaml_planes(p))),
                     "workpiece.datum.probe_planes[2]: the points are not on one plane");
    expect_job_error(
        f.write("job.yaml", job_text("mm", "{probe_planes: [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]}", datum)),
        "fiducials[0].pose.probe_planes: expected 3 lists of probed points");
    expect_job_error(f.write("job.yaml", job_text("mm", "{probe_planes: [[[0, 0]], [], []]}", datum)),
                     "fiducials[0].pose.probe_planes[0][0]: expected 3 numbers, found 2 items");
    expect_job_error(
        f.write("job.yaml", job_text("mm", "{probe_planes: [[], [], []], origin: [0, 0, 0]}", datum)),
        "fiducials[0].pose.origin: unknown field (known here: probe_planes)");
    expect_job_error(
        f.write("job.yaml", job_text("mm", "{orign: [0, 0, 0]}", datum)),
        "fiducials[0].pose.orign: unknown field (known here: origin, euler_xyz_deg, matrix, probe_planes)");

    // From the command line: exit 2, one line on stderr, nothing written.
    p = good;
    p[0].resize(1);
    const fs::path job = f.write("job.yaml", job_text("mm", yaml_planes(p), datum));
    const std::string cmd = std::string(PARTLOC_EXE) + " run " + job.string() + " --out " +
                            (f.dir / "out").string() + " 2> " + (f.dir / "stderr.txt").string() +
                            " > /dev/null";
    const int status = std::system(cmd.c_str());
    EXPECT_EQ(WEXITSTATUS(status), 2);
    std::ifstream err(f.dir / "stderr.txt");
    std::string line, rest;
    std::getline(err, line);
    EXPECT_NE(line.find("fiducials[0].pose.probe_planes[0]: needs at least 3 points, found 1"),
              std::string::npos)
        << line;
    EXPECT_FALSE(std::getline(err, rest)) << rest;
    EXPECT_FALSE(fs::exists(f.dir / "out" / "result.json"));
}
