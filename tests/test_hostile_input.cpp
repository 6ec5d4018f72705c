// Hostile and degenerate input from the outside (issue 28): a corpus of small files made here, each run
// through `partloc run` with a time limit. SPEC's promise for every one: exit 2 with one line naming the
// file (or 3 with a reason for data that is valid but shows nothing), never 1, never a hang; a file's
// lying count costs no more than its size; the output folder tells one run's story.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <thread>

#include "partloc/core/extent.hpp"
#include "partloc/core/ppf.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/output_lock.hpp"
#include "partloc/pipeline/run.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;
using namespace partloc::test;

namespace {

struct Outcome {
    int code = -1;
    std::string out, err;
    double seconds = 0;
};

std::string ply_ascii(const std::vector<Eigen::Vector3d>& pts, const std::string& count = "",
                      const std::string& extra_elements = "") {
    std::ostringstream s;
    s << "ply\nformat ascii 1.0\nelement vertex " << (count.empty() ? std::to_string(pts.size()) : count)
      << "\nproperty float x\nproperty float y\nproperty float z\n"
      << extra_elements << "end_header\n";
    s.precision(17);
    for (const auto& p : pts) s << p.x() << " " << p.y() << " " << p.z() << "\n";
    return s.str();
}

/// A job folder as test_cli_run's: a box fiducial (STL), a slab as reference surfaces, one scan of both.
class Hostile : public ::testing::Test {
  protected:
    void SetUp() override {
        open3d::geometry::TriangleMesh box;
        for (int i = 0; i < 8; ++i)
            box.vertices_.emplace_back(30.0 * (i & 1), 20.0 * ((i >> 1) & 1), 10.0 * (i >> 2));
        box.triangles_ = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                          {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
        io::write_mesh(dir() / "models/box.stl", box);
        for (int i = 0; i < 40; ++i)
            for (int j = 0; j < 40; ++j) slab_.emplace_back(-100 + 2.0 * i, -100 + 2.0 * j, 5.0);
        spit(dir() / "models/slab.ply", ply_ascii(slab_));
        for (int i = 0; i <= 30; ++i)
            for (int j = 0; j <= 20; ++j) scan_.emplace_back(i, j, 10.0);
        for (int i = 0; i <= 30; ++i)
            for (int k = 0; k < 10; ++k) scan_.emplace_back(i, 0.0, k);
        for (int j = 0; j <= 20; ++j)
            for (int k = 0; k < 10; ++k) scan_.emplace_back(0.0, j, k);
        scan_.insert(scan_.end(), slab_.begin(), slab_.end());
        spit(dir() / "scans/scan_01.ply", ply_ascii(scan_));
    }

    const fs::path& dir() const { return folder_.dir; }

    std::string job(const std::string& scan = "scans/scan_01.ply",
                    const std::string& fiducial = "models/box.stl",
                    const std::string& reference = "models/slab.ply",
                    const std::string& datum = "[-100, -100, 5]", const std::string& extra = "") const {
        return "units: mm\n" + extra + "fiducials:\n  - name: box\n    model: " + fiducial +
               "\n    pose: {origin: [0, 0, 0], euler_xyz_deg: [0, 0, 0]}\n"
               "workpiece:\n  reference_surfaces: " +
               reference + "\n  datum: {origin: " + datum + "}\nscans:\n  - " + scan + "\n";
    }

    fs::path write_job(const std::string& text, const std::string& name = "job.yaml") const {
        return folder_.write(name, text);
    }

    /// `partloc run` under a time limit of 60 s (a hang is exit 124).
    Outcome run(const fs::path& job_file, const fs::path& out) const {
        const fs::path out_txt = dir() / "stdout.txt", err_txt = dir() / "stderr.txt";
        const std::string cmd = "PARTLOC_CACHE='" + (dir() / "cache").string() + "' timeout 60 '" +
                                PARTLOC_EXE + "' run '" + job_file.string() + "' --out '" + out.string() +
                                "' --threads 2 > '" + out_txt.string() + "' 2> '" + err_txt.string() + "'";
        const auto start = std::chrono::steady_clock::now();
        const int status = std::system(cmd.c_str());
        Outcome r;
        r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
        r.out = slurp(out_txt);
        r.err = slurp(err_txt);
        return r;
    }

    /// Exit 2 within a few seconds, one line on stderr naming `file` and holding `phrase`, nothing in out.
    void expect_bad(const std::string& job_text, const std::string& file, const std::string& phrase) const {
        const fs::path out = dir() / "out_bad";
        fs::remove_all(out);
        const Outcome r = run(write_job(job_text), out);
        EXPECT_EQ(r.code, 2) << r.err;
        EXPECT_LT(r.seconds, 20) << r.err;
        EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
        EXPECT_NE(r.err.find("partloc: " + file + ": "), std::string::npos) << r.err;
        EXPECT_NE(r.err.find(phrase), std::string::npos) << r.err;
        EXPECT_TRUE(!fs::exists(out) || fs::is_empty(out));
    }

    /// Exit 0 or 3 (never 1, never a hang), with result.json; returns it.
    nlohmann::json expect_runs(const std::string& job_text, const fs::path& out) const {
        const Outcome r = run(write_job(job_text), out);
        EXPECT_TRUE(r.code == 0 || r.code == 3) << "exit " << r.code << ": " << r.err;
        EXPECT_LT(r.seconds, 30) << r.err;
        if (!fs::exists(out / "result.json")) {
            ADD_FAILURE() << "no result.json: " << r.err;
            return {};
        }
        last_err_ = r.err;
        return nlohmann::json::parse(slurp(out / "result.json"));
    }

    static std::string without_seconds(std::string json) {
        return std::regex_replace(json, std::regex("\"seconds\": [^,\\n]*"), "");
    }

    TempFolder folder_{"partloc_test_hostile"};
    std::vector<Eigen::Vector3d> scan_, slab_;
    mutable std::string last_err_;
};

// --- counts against the file's size ---

TEST_F(Hostile, PlyElementOf10e12WithoutPropertiesDoesNotHang) {
    for (const char* format : {"ascii", "binary_little_endian"}) {
        std::string bytes = ply_ascii(scan_, "", "element junk 1000000000000\n");
        if (std::string(format) != "ascii") {
            // The same points as binary floats.
            bytes = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(scan_.size()) +
                    "\nproperty float x\nproperty float y\nproperty float z\nelement junk 1000000000000\n"
                    "end_header\n";
            for (const auto& p : scan_)
                for (int k = 0; k < 3; ++k) {
                    const float f = static_cast<float>(p[k]);
                    bytes.append(reinterpret_cast<const char*>(&f), 4);
                }
        }
        spit(dir() / "scans/junk.ply", bytes);
        expect_runs(job("scans/junk.ply"), dir() / ("out_" + std::string(format)));
    }
}

TEST_F(Hostile, PlyCountOf10e12InASmallFile) {
    spit(dir() / "scans/big.ply", ply_ascii({{0, 0, 0}, {1, 0, 0}}, "1000000000000"));
    expect_bad(job("scans/big.ply"), "scans/big.ply", "truncated");
}

TEST_F(Hostile, VtkPointsBeyondSizeT) {
    // fuzz_vtk's first finding: a count of 3e40 cast to size_t (undefined).
    spit(dir() / "scans/big.vtk",
         "# vtk DataFile Version 3.0\nscan\nASCII\nDATASET POLYDATA\n"
         "POINTS 33333333333333333333333333333333333333333 float\n0 0 0\n");
    expect_bad(job("scans/big.vtk"), "scans/big.vtk", "expected 'POINTS COUNT TYPE'");
}

TEST_F(Hostile, PcdPointsOf10e9And2e31InASmallAsciiFile) {
    for (const char* points : {"1000000000", "2147483648"}) {
        spit(dir() / "scans/big.pcd",
             std::string("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                         "WIDTH ") +
                 points + "\nHEIGHT 1\nPOINTS " + points + "\nDATA ascii\n0 0 0\n1 0 0\n0 1 0\n");
        expect_bad(job("scans/big.pcd"), "scans/big.pcd", "truncated");
    }
}

TEST_F(Hostile, PcdCountOf10e12PerPointAsksNoMemory) {
    // values_per_point came from COUNT: the ascii reader asked for 8 TB.
    spit(dir() / "scans/count.pcd",
         "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1000000000000\n"
         "WIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n0 0 0\n1 0 0\n0 1 0\n");
    expect_bad(job("scans/count.pcd"), "scans/count.pcd", "truncated");
    spit(dir() / "scans/count.pcd",
         "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1000000000000\n"
         "WIDTH 1000000000000\nHEIGHT 1\nPOINTS 1000000000000\nDATA binary\n0000");
    expect_bad(job("scans/count.pcd"), "scans/count.pcd", "");
}

TEST_F(Hostile, CountsSmallerThanTheDataAreAWarning) {
    // PLY: 10 vertices fewer in the header than in the file.
    spit(dir() / "scans/short.ply", ply_ascii(scan_, std::to_string(scan_.size() - 10)));
    nlohmann::json r = expect_runs(job("scans/short.ply"), dir() / "out_ply");
    ASSERT_TRUE(r.contains("warnings")) << r.dump();
    EXPECT_NE(r["warnings"].dump().find("scans/short.ply: data continues after"), std::string::npos);
    EXPECT_NE(last_err_.find("warning: scans/short.ply"), std::string::npos) << last_err_;
    // VTK: a POINTS count 10 short.
    std::ostringstream vtk;
    vtk << "# vtk DataFile Version 3.0\nscan\nASCII\nDATASET POLYDATA\nPOINTS " << scan_.size() - 10
        << " float\n";
    for (const auto& p : scan_) vtk << p.x() << " " << p.y() << " " << p.z() << "\n";
    spit(dir() / "scans/short.vtk", vtk.str());
    r = expect_runs(job("scans/short.vtk"), dir() / "out_vtk");
    ASSERT_TRUE(r.contains("warnings"));
    EXPECT_NE(r["warnings"].dump().find("scans/short.vtk: numbers continue"), std::string::npos);
    // PCD binary: 10 points more than the header's.
    std::string pcd = "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH " +
                      std::to_string(scan_.size() - 10) + "\nHEIGHT 1\nPOINTS " +
                      std::to_string(scan_.size() - 10) + "\nVIEWPOINT 0 0 0 1 0 0 0\nDATA binary\n";
    for (const auto& p : scan_)
        for (int k = 0; k < 3; ++k) {
            const float f = static_cast<float>(p[k]);
            pcd.append(reinterpret_cast<const char*>(&f), 4);
        }
    spit(dir() / "scans/short.pcd", pcd);
    r = expect_runs(job("scans/short.pcd"), dir() / "out_pcd");
    ASSERT_TRUE(r.contains("warnings"));
    EXPECT_NE(r["warnings"].dump().find("scans/short.pcd: the data holds 120 bytes more"), std::string::npos);
}

// --- special files ---

TEST_F(Hostile, DevicesAndPipesAreRefused) {
    expect_bad(job("/dev/zero"), "/dev/zero", "");  // refused by its name already
    // Behind names that look like scans: grew to 6 GB until killed.
    fs::create_symlink("/dev/zero", dir() / "scans/zero.ply");
    expect_bad(job("scans/zero.ply"), "scans/zero.ply", "not a regular file");
    fs::create_symlink("/dev/urandom", dir() / "scans/random.pcd");
    expect_bad(job("scans/random.pcd"), "scans/random.pcd", "not a regular file");
    const fs::path fifo = dir() / "scans/fifo.ply";
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
    expect_bad(job("scans/fifo.ply"), "scans/fifo.ply", "not a regular file");
    // The job file itself.
    const Outcome r = run("/dev/zero", dir() / "out_devjob");
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find("/dev/zero: is not a regular file"), std::string::npos) << r.err;
}

// --- degenerate geometry ---

TEST_F(Hostile, DegenerateScans) {
    std::vector<Eigen::Vector3d> planar, line, same;
    for (int i = 0; i < 50; ++i)
        for (int j = 0; j < 50; ++j) planar.emplace_back(i, j, 0.0);
    for (int i = 0; i < 500; ++i) line.emplace_back(i, 2.0 * i, -i);
    for (int i = 0; i < 500; ++i) same.emplace_back(1.5, 2.5, 3.5);
    spit(dir() / "scans/planar.ply", ply_ascii(planar));
    expect_bad(job("scans/planar.ply"), "scans/planar.ply", "lie in one plane");
    spit(dir() / "scans/line.ply", ply_ascii(line));
    expect_bad(job("scans/line.ply"), "scans/line.ply", "lie on one line");
    spit(dir() / "scans/same.ply", ply_ascii(same));
    expect_bad(job("scans/same.ply"), "scans/same.ply", "one and the same point");
    spit(dir() / "scans/none.ply", ply_ascii({}));
    expect_bad(job("scans/none.ply"), "scans/none.ply", "no points");
    spit(dir() / "scans/one.ply", ply_ascii({{1, 2, 3}}));
    expect_bad(job("scans/one.ply"), "scans/one.ply", "has only 1 point");
    spit(dir() / "scans/two.ply", ply_ascii({{1, 2, 3}, {4, 5, 6}}));
    expect_bad(job("scans/two.ply"), "scans/two.ply", "has only 2 points");
}

TEST_F(Hostile, HugeCoordinatesAreRefused) {
    std::vector<Eigen::Vector3d> huge = scan_;
    for (auto& p : huge) p = p * 1e300 + Eigen::Vector3d::Constant(1e307);
    spit(dir() / "scans/huge.ply", ply_ascii(huge));
    expect_bad(job("scans/huge.ply"), "scans/huge.ply", "coordinates reach");
    std::vector<Eigen::Vector3d> box;
    for (int i = 0; i < 8; ++i)
        box.emplace_back(1e38 + 30.0 * (i & 1) * 1e37, 20.0 * ((i >> 1) & 1), 10.0 * (i >> 2));
    spit(dir() / "models/far.ply", ply_ascii(box));
    expect_bad(job("scans/scan_01.ply", "models/far.ply"), "models/far.ply", "coordinates reach");
}

TEST_F(Hostile, DegenerateFiducials) {
    spit(dir() / "models/three.ply", ply_ascii({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}));
    expect_bad(job("scans/scan_01.ply", "models/three.ply"), "models/three.ply", "has only 3 points");
    std::vector<Eigen::Vector3d> flat;
    for (int i = 0; i < 20; ++i)
        for (int j = 0; j < 20; ++j) flat.emplace_back(i, j, 0.0);
    spit(dir() / "models/flat.ply", ply_ascii(flat));
    expect_bad(job("scans/scan_01.ply", "models/flat.ply"), "models/flat.ply", "lie in one plane");
    // A fiducial 10^6 times larger than the scan: bad_alloc after 29 s, and a signed overflow in PpfModel.
    std::vector<Eigen::Vector3d> giant, beyond;
    for (int i = 0; i < 8; ++i) {
        giant.emplace_back(3e5 * (i & 1), 2e5 * ((i >> 1) & 1), 1e5 * (i >> 2));
        beyond.push_back(giant.back() * 1e6 / 1e4);
    }
    spit(dir() / "models/giant.ply", ply_ascii(giant));
    expect_bad(job("scans/scan_01.ply", "models/giant.ply"), "models/giant.ply",
               "times larger than the largest scan");
    spit(dir() / "models/beyond.ply", ply_ascii(beyond));
    expect_bad(job("scans/scan_01.ply", "models/beyond.ply"), "models/beyond.ply", "coordinates reach");
}

TEST_F(Hostile, DegenerateReferenceSurfaces) {
    // One plane (the slab) is a plate's top and runs; three points in a plane run too, or say why not.
    spit(dir() / "models/ref3.ply", ply_ascii({{-100, -100, 5}, {-20, -100, 5}, {-100, -20, 5}}));
    expect_runs(job("scans/scan_01.ply", "models/box.stl", "models/ref3.ply"), dir() / "out_ref3");
    std::vector<Eigen::Vector3d> line;
    for (int i = 0; i < 40; ++i) line.emplace_back(-100 + 2.0 * i, -100, 5);
    spit(dir() / "models/refline.ply", ply_ascii(line));
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/refline.ply"), "models/refline.ply",
               "lie on one line");
    spit(dir() / "models/ref2.ply", ply_ascii({{-100, -100, 5}, {-20, -100, 5}}));
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/ref2.ply"), "models/ref2.ply",
               "has only 2");
}

TEST_F(Hostile, TinyScannerSpacingIsRefused) {
    const fs::path job_file = dir() / "job.yaml";
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[-100, -100, 5]",
                   "scanner: {point_spacing: 1e-9}\n"),
               job_file.string(), "scanner.point_spacing");
}

TEST_F(Hostile, OneFarPointIsDroppedWithAWarning) {
    const nlohmann::json plain = expect_runs(job(), dir() / "out_plain");
    std::vector<Eigen::Vector3d> with_far = scan_;
    with_far.emplace_back(1e9, 0, 0);
    spit(dir() / "scans/far.ply", ply_ascii(with_far));
    const nlohmann::json far = expect_runs(job("scans/far.ply"), dir() / "out_far");
    ASSERT_FALSE(plain.is_null());
    ASSERT_FALSE(far.is_null());
    EXPECT_EQ(far["status"], plain["status"]);
    EXPECT_EQ(far["scans"][0]["status"], plain["scans"][0]["status"]);
    EXPECT_EQ(far["scans"][0]["T_machine_scan"], plain["scans"][0]["T_machine_scan"]);
    ASSERT_TRUE(far.contains("warnings"));
    EXPECT_NE(far["warnings"].dump().find("scans/far.ply: 1 point lies"), std::string::npos)
        << far["warnings"];
    // The plain job's one warning is the box's: a box maps onto itself by half turns.
    ASSERT_TRUE(plain.contains("warnings"));
    ASSERT_EQ(plain["warnings"].size(), 1u) << plain["warnings"];
    EXPECT_EQ(plain["warnings"][0].get<std::string>().rfind("fiducial box cannot place a scan alone", 0), 0u)
        << plain["warnings"];
}

/// Input at the edge of what the load checks let through: exit 2 naming a file, or 0 / 3; never 1.
TEST_F(Hostile, NearlyDegenerateInputIsNeverAnInternalError) {
    std::vector<Eigen::Vector3d> few, thin, tetra, random_fid, dup;
    for (int i = 0; i < 12; ++i) few.emplace_back(i * 3 % 7, i * 5 % 11, i * 7 % 13);
    for (int i = 0; i < 50; ++i)
        for (int j = 0; j < 50; ++j) thin.emplace_back(i, j, ((i * 31 + j * 17) % 5) * 1e-5);
    tetra = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
    for (int i = 0; i < 50; ++i) random_fid.emplace_back(i * 13 % 29, i * 7 % 17, i * 11 % 19);
    dup = scan_;
    for (int i = 0; i < 3000; ++i) dup.push_back(scan_[0]);
    const std::pair<std::string, std::string> cases[] = {{"scans/few.ply", "models/box.stl"},
                                                         {"scans/thin.ply", "models/box.stl"},
                                                         {"scans/dup.ply", "models/box.stl"},
                                                         {"scans/scan_01.ply", "models/tetra.ply"},
                                                         {"scans/scan_01.ply", "models/random.ply"}};
    spit(dir() / "scans/few.ply", ply_ascii(few));
    spit(dir() / "scans/thin.ply", ply_ascii(thin));
    spit(dir() / "scans/dup.ply", ply_ascii(dup));
    spit(dir() / "models/tetra.ply", ply_ascii(tetra));
    spit(dir() / "models/random.ply", ply_ascii(random_fid));
    int k = 0;
    for (const auto& [scan, fiducial] : cases) {
        const Outcome r = run(write_job(job(scan, fiducial)), dir() / ("out_edge" + std::to_string(k++)));
        EXPECT_TRUE(r.code == 0 || r.code == 2 || r.code == 3)
            << scan << " " << fiducial << ": exit " << r.code << ": " << r.err;
        EXPECT_LT(r.seconds, 30);
        if (r.code == 2)
            EXPECT_TRUE(r.err.find(scan) != std::string::npos || r.err.find(fiducial) != std::string::npos)
                << r.err;
    }
}

// --- the job's numbers ---

TEST_F(Hostile, AbsurdNumbersInTheJobAreRefused) {
    const std::string job_file = (dir() / "job.yaml").string();
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[1e308, 0, 0]"), job_file,
               "workpiece.datum.origin");
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[.nan, 0, 0]"), job_file,
               "workpiece.datum.origin[0]: expected a number");
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[1e999, 0, 0]"), job_file,
               "workpiece.datum.origin[0]: expected a number");
    expect_bad(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply",
                   "[0, 0, 0], euler_xyz_deg: [1e300, 0, 0]"),
               job_file, "euler_xyz_deg");
}

TEST_F(Hostile, AxisDirectionLengthDoesNotMatter) {
    std::string results[3];
    const char* directions[] = {"[1, 0, 0]", "[1e200, 0, 0]", "[1e-200, 0, 0]"};
    for (int i = 0; i < 3; ++i) {
        const std::string machine =
            std::string("machine:\n  axes:\n    - {name: A, type: rotary, direction: ") + directions[i] +
            ", point: [0, 0, 0]}\n";
        std::string text = job("{file: scans/scan_01.ply, axes: {A: 0}}", "models/box.stl", "models/slab.ply",
                               "[-100, -100, 5]", machine);
        const Job loaded = io::load_job(write_job(text));
        ASSERT_EQ(loaded.machine.axes.size(), 1u);
        EXPECT_EQ(loaded.machine.axes[0].direction, Eigen::Vector3d(1, 0, 0)) << directions[i];
        expect_runs(text, dir() / ("out_axis" + std::to_string(i)));
        results[i] = without_seconds(slurp(dir() / ("out_axis" + std::to_string(i)) / "result.json"));
    }
    EXPECT_EQ(results[1], results[0]);
    EXPECT_EQ(results[2], results[0]);
    // Not along an axis: the same as the unit vector, to the last bit or one.
    const Job tilted = io::load_job(
        write_job(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[-100, -100, 5]",
                      "machine:\n  axes:\n    - {name: A, type: linear, direction: "
                      "[3e200, 4e200, 0]}\n")));
    EXPECT_NEAR((tilted.machine.axes[0].direction - Eigen::Vector3d(0.6, 0.8, 0)).norm(), 0, 1e-15);
    expect_job_error(
        write_job(job("scans/scan_01.ply", "models/box.stl", "models/slab.ply", "[-100, -100, 5]",
                      "machine:\n  axes:\n    - {name: A, type: linear, direction: [0, 0, 0]}\n")),
        "must not be zero");
}

// --- names and the output folder ---

TEST_F(Hostile, FileNameThatIsNotUtf8IsWrittenEscaped) {
    const std::string name = "scans/scan_\xff\xfe.ply";
    spit(dir() / name, ply_ascii(scan_));
    const nlohmann::json r = expect_runs(job(name), dir() / "out_utf8");
    ASSERT_FALSE(r.is_null());
    EXPECT_EQ(r["scans"][0]["file"].get<std::string>(), "scans/scan_\xEF\xBF\xBD\xEF\xBF\xBD.ply");
}

TEST_F(Hostile, SecondRunIntoAFolderInUseIsRefused) {
    const fs::path out = dir() / "out_locked";
    io::OutputFolderLock held(out);
    const Outcome r = run(write_job(job()), out);
    EXPECT_EQ(r.code, 2) << r.err;
    EXPECT_NE(r.err.find("another partloc run is writing into this folder"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out / "result.json"));
}

TEST_F(Hostile, TheLockLeavesNothingInTheFolder) {
    const fs::path out = dir() / "out_lockfile";
    expect_runs(job(), out);
    EXPECT_TRUE(fs::exists(out / "result.json"));
    EXPECT_FALSE(fs::exists(out / ".partloc.lock"));
    {
        io::OutputFolderLock first(out);
        EXPECT_TRUE(fs::exists(out / ".partloc.lock"));
        EXPECT_THROW(io::OutputFolderLock second(out), io::FolderBusy);
    }
    EXPECT_FALSE(fs::exists(out / ".partloc.lock"));
    io::OutputFolderLock again(out);  // given up, it can be taken again
    EXPECT_TRUE(fs::exists(out / ".partloc.lock"));
}

TEST_F(Hostile, KilledRunsTemporariesAreRemovedByTheNextRun) {
    const fs::path out = dir() / "out_tmp";
    spit(out / ".tmp-99999-0-merged.ply", "half a file");
    spit(out / ".tmp-x-merged.ply", "not ours");
    expect_runs(job(), out);
    EXPECT_FALSE(fs::exists(out / ".tmp-99999-0-merged.ply"));
    EXPECT_TRUE(fs::exists(out / ".tmp-x-merged.ply"));
    EXPECT_TRUE(io::is_atomic_temporary(".tmp-12-3-result.json"));
    EXPECT_FALSE(io::is_atomic_temporary(".tmp-12-result.json"));
}

TEST_F(Hostile, AFailedRerunLeavesNoOlderResultBesideNewerFiles) {
    const fs::path out = dir() / "out_rerun";
    expect_runs(job(), out);
    ASSERT_TRUE(fs::exists(out / "result.json"));
    // The report cannot be replaced (a folder in its place), as on a full disk: exit 1, and the older
    // result.json is gone rather than left beside this run's other files.
    fs::remove(out / "report.html");
    fs::create_directories(out / "report.html" / "x");
    const Outcome r = run(write_job(job()), out);
    EXPECT_EQ(r.code, 1) << r.err;
    EXPECT_NE(r.err.find("cannot write the output"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out / "result.json"));
}

// A program that calls the library (load_job, then run_job) without io::check_job_geometry gets a degenerate
// scan rejected with its reason, and a degenerate fiducial refused as std::invalid_argument: never an error
// from inside Open3D or Qhull.
TEST_F(Hostile, RunJobAloneRejectsDegenerateScansWithAReason) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const Job loaded = io::load_job(write_job(job()));
    std::vector<Eigen::Vector3d> planar, line, same;
    for (int i = 0; i < 60; ++i)
        for (int j = 0; j < 60; ++j) planar.emplace_back(i, j, 0.0);
    for (int i = 0; i < 3000; ++i) line.emplace_back(0.01 * i, 0.02 * i, -0.01 * i);
    for (int i = 0; i < 3000; ++i) same.emplace_back(1.5, 2.5, 3.5);
    const std::vector<std::pair<std::vector<Eigen::Vector3d>, std::string>> cases = {
        {planar, "lie in one plane"},
        {line, "lie on one line"},
        {same, "one and the same point"},
        {{}, "too few"},
        {{{1, 2, 3}, {4, 5, 6}}, "too few"}};
    for (const auto& [points, phrase] : cases) {
        Job j = loaded;
        Scan degenerate = j.scans[0];
        degenerate.file = "degenerate.ply";
        degenerate.points = std::make_shared<open3d::geometry::PointCloud>(points);
        j.scans.push_back(degenerate);
        RunSettings rs;
        rs.build_stock = false;
        JobResult r;
        ASSERT_NO_THROW(r = run_job(j, rs)) << phrase;
        ASSERT_EQ(r.scans.size(), 2u);
        EXPECT_FALSE(r.scans[1].valid);
        EXPECT_NE(r.scans[1].reason.find(phrase), std::string::npos) << r.scans[1].reason;
    }
    Job flat = loaded;
    auto mesh = std::make_shared<open3d::geometry::TriangleMesh>();
    mesh->vertices_ = {{0, 0, 0}, {30, 0, 0}, {0, 20, 0}, {30, 20, 0}};
    mesh->triangles_ = {{0, 1, 2}, {1, 3, 2}};
    flat.fiducials[0].model.mesh = mesh;
    try {
        run_job(flat, RunSettings{});
        ADD_FAILURE() << "a flat fiducial ran";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("lie in one plane"), std::string::npos) << e.what();
    }
}

// --- the library's numeric guards ---

TEST(HostileCore, PpfModelOfAHugeModelThrowsInsteadOfOverflowing) {
    std::vector<Eigen::Vector3d> points, normals;
    for (int i = 0; i < 8; ++i) {
        points.emplace_back(3e7 * (i & 1), 2e7 * ((i >> 1) & 1), 1e7 * (i >> 2));
        normals.emplace_back(0, 0, 1);
    }
    PpfSettings settings;
    settings.sampling = 1.0;
    EXPECT_THROW(PpfModel(points, normals, settings), std::invalid_argument);
}

TEST(HostileCore, ExtentAndRank) {
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 10; ++i)
        for (int j = 0; j < 10; ++j) pts.emplace_back(1e300 + i * 1e290, j * 1e290, 0);
    EXPECT_EQ(extent_of(pts).rank, 2);
    pts.back().z() = 5e289;
    EXPECT_EQ(extent_of(pts).rank, 3);
    EXPECT_EQ(extent_of({{1, 1, 1}, {1, 1, 1}}).rank, 0);
    EXPECT_EQ(extent_of({{0, 0, 0}, {1e-200, 0, 0}}).rank, 1);
    std::vector<Eigen::Vector3d> cloud, normals;
    for (int i = 0; i < 100; ++i) cloud.emplace_back(i, i % 7, i % 3);
    const auto before = cloud;
    EXPECT_EQ(remove_far_points(cloud, normals), 0u);
    EXPECT_EQ(cloud, before);
    cloud.emplace_back(1e9, 0, 0);
    cloud.emplace_back(0, -1e308, 0);
    EXPECT_EQ(remove_far_points(cloud, normals), 2u);
    EXPECT_EQ(cloud, before);
}

}  // namespace
