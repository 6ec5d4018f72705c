// `build/partloc run` from the outside (SPEC "Commands"): bad input exits 2 with one line on stderr naming
// the file and leaves no file in --out; a good job exits 0 or 3 with result.json saying which.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "partloc/io/cloud_io.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;

using namespace partloc::test;

namespace {

struct Outcome {
    int code = -1;
    std::string out, err;
};

/// A job folder with a box fiducial (STL), a slab as reference surfaces (PLY points) and one scan of both.
class CliRun : public ::testing::Test {
  protected:
    void SetUp() override {
        static std::atomic<int> n{0};
        dir_ = fs::temp_directory_path() /
               ("partloc_test_cli_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
        fs::remove_all(dir_);
        fs::create_directories(dir_);

        open3d::geometry::TriangleMesh box;
        for (int i = 0; i < 8; ++i)
            box.vertices_.emplace_back(30.0 * (i & 1), 20.0 * ((i >> 1) & 1), 10.0 * (i >> 2));
        box.triangles_ = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                          {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
        partloc::io::write_mesh(dir_ / "models/box.stl", box);

        open3d::geometry::PointCloud slab, scan;
        for (int i = 0; i < 40; ++i)
            for (int j = 0; j < 40; ++j) slab.points_.emplace_back(-100 + 2.0 * i, -100 + 2.0 * j, 5.0);
        partloc::io::write_point_cloud(dir_ / "models/slab.ply", slab);
        // The scan sees the box's top and two sides, and the slab, in the machine frame (identity pose).
        for (int i = 0; i <= 30; ++i)
            for (int j = 0; j <= 20; ++j) scan.points_.emplace_back(i, j, 10.0);
        for (int i = 0; i <= 30; ++i)
            for (int k = 0; k < 10; ++k) scan.points_.emplace_back(i, 0.0, k);
        for (int j = 0; j <= 20; ++j)
            for (int k = 0; k < 10; ++k) scan.points_.emplace_back(0.0, j, k);
        scan += slab;
        partloc::io::write_point_cloud(dir_ / "scans/scan_01.ply", scan);
    }
    void TearDown() override {
        std::error_code ec;
        fs::remove_all(dir_, ec);
    }

    std::string job(const std::string& scan_entry = "scans/scan_01.ply",
                    const std::string& units = "mm") const {
        return "units: " + units +
               "\nfiducials:\n  - name: box\n    model: models/box.stl\n    pose: {origin: [0, 0, 0], "
               "euler_xyz_deg: [0, 0, 0]}\n"
               "workpiece:\n  reference_surfaces: models/slab.ply\n  datum: {origin: [-100, -100, 5]}\n"
               "scans:\n  - " +
               scan_entry + "\n";
    }

    /// The model cache in this test's folder (PARTLOC_CACHE), unless `options` name another.
    Outcome run(const fs::path& job_file, const fs::path& out, const std::string& options = "") const {
        const fs::path out_txt = dir_ / "stdout.txt", err_txt = dir_ / "stderr.txt";
        const std::string cmd = "PARTLOC_CACHE='" + (dir_ / "cache").string() + "' '" + PARTLOC_EXE +
                                "' run '" + job_file.string() + "' --out '" + out.string() +
                                "' --threads 2 " + options + " > '" + out_txt.string() + "' 2> '" +
                                err_txt.string() + "'";
        const int status = std::system(cmd.c_str());
        Outcome r;
        r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
        r.out = slurp(out_txt);
        r.err = slurp(err_txt);
        return r;
    }

    /// Exit 2, exactly one line on stderr that names `file` (and holds `phrase`), nothing in `out`.
    void expect_bad_input(const fs::path& job_file, const std::string& file, const std::string& phrase) {
        const fs::path out = dir_ / "out";
        const Outcome r = run(job_file, out);
        EXPECT_EQ(r.code, 2) << r.err;
        EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
        EXPECT_NE(r.err.find(file), std::string::npos) << r.err;
        EXPECT_NE(r.err.find(phrase), std::string::npos) << r.err;
        const bool empty = !fs::exists(out) || fs::is_empty(out);
        EXPECT_TRUE(empty) << "files left in " << out;
    }

    fs::path dir_;
};

}  // namespace

TEST_F(CliRun, MissingJobFile) { expect_bad_input(dir_ / "nope.yaml", "nope.yaml", "no such file"); }

TEST_F(CliRun, MalformedYaml) {
    spit(dir_ / "job.yaml", "units: mm\nfiducials: [ {name: box\n");
    expect_bad_input(dir_ / "job.yaml", "job.yaml", "not valid YAML");
}

TEST_F(CliRun, UnknownUnit) {
    spit(dir_ / "job.yaml", job("scans/scan_01.ply", "furlong"));
    expect_bad_input(dir_ / "job.yaml", "job.yaml", "units: unknown unit 'furlong'");
}

TEST_F(CliRun, MissingField) {
    std::string text = job();
    text.erase(text.find("workpiece:"), text.find("scans:") - text.find("workpiece:"));
    spit(dir_ / "job.yaml", text);
    expect_bad_input(dir_ / "job.yaml", "job.yaml", "workpiece: missing");
}

TEST_F(CliRun, MissingScanFile) {
    spit(dir_ / "job.yaml", job("scans/absent.ply"));
    expect_bad_input(dir_ / "job.yaml", "scans/absent.ply", "no such file");
}

TEST_F(CliRun, TruncatedScan) {
    const std::string bytes = slurp(dir_ / "scans/scan_01.ply");
    spit(dir_ / "scans/cut.ply", bytes.substr(0, bytes.size() / 2));
    spit(dir_ / "job.yaml", job("scans/cut.ply"));
    expect_bad_input(dir_ / "job.yaml", "scans/cut.ply", "file is truncated");
}

TEST_F(CliRun, NanOnlyScanAndExistingOutFolderStaysEmpty) {
    spit(dir_ / "scans/nan.xyz", "nan nan nan\nnan nan nan\n");
    spit(dir_ / "job.yaml", job("scans/nan.xyz"));
    fs::create_directories(dir_ / "out");
    expect_bad_input(dir_ / "job.yaml", "scans/nan.xyz", "no finite points");
    EXPECT_TRUE(fs::is_directory(dir_ / "out"));
}

TEST_F(CliRun, OutIsAFile) {
    spit(dir_ / "job.yaml", job());
    spit(dir_ / "out", "not a folder");
    const Outcome r = run(dir_ / "job.yaml", dir_ / "out");
    EXPECT_EQ(r.code, 2);
    EXPECT_NE(r.err.find("not a folder"), std::string::npos) << r.err;
    EXPECT_EQ(slurp(dir_ / "out"), "not a folder");
}

TEST_F(CliRun, GoodJobWritesResultThatAgreesWithTheExitCode) {
    spit(dir_ / "job.yaml", job());
    const Outcome r = run(dir_ / "job.yaml", dir_ / "out");
    ASSERT_TRUE(r.code == 0 || r.code == 3) << "exit " << r.code << ": " << r.err;
    EXPECT_EQ(r.err, "");
    const auto j = nlohmann::json::parse(slurp(dir_ / "out/result.json"));
    EXPECT_EQ(j.at("status"), r.code == 0 ? "located" : "not_located");
    EXPECT_EQ(j.at("units"), "mm");
    EXPECT_TRUE(fs::exists(dir_ / "out/report.html"));
    if (fs::exists(dir_ / "out/merged.ply"))
        EXPECT_NO_THROW(partloc::io::read_point_cloud(dir_ / "out/merged.ply", "merged.ply"));
    for (const auto& e : fs::directory_iterator(dir_ / "out"))
        EXPECT_NE(e.path().filename().string().rfind(".tmp", 0), 0u) << "temporary file left: " << e.path();
    EXPECT_NE(r.out.find("workpiece:"), std::string::npos) << r.out;
}

namespace {
/// result.json without its run times.
std::string without_seconds(const std::string& json) {
    std::istringstream in(json);
    std::string out, line;
    while (std::getline(in, line))
        if (line.find("\"seconds\"") == std::string::npos) out += line + "\n";
    return out;
}
std::size_t model_files(const fs::path& dir) {
    std::size_t n = 0;
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
        n += it->path().extension() == ".model";
    return n;
}
}  // namespace

// The fiducials' prepared models are kept between runs (io/model_cache.hpp): by default in $PARTLOC_CACHE,
// or in --cache DIR; --no-cache keeps nothing. A damaged cache file or a cache folder that cannot be
// written is said on stderr, and the result is the same.
TEST_F(CliRun, ModelCacheKeepsTheResultAndSaysWhatItCouldNotDo) {
    spit(dir_ / "job.yaml", job());
    const Outcome first = run(dir_ / "job.yaml", dir_ / "out1");
    ASSERT_TRUE(first.code == 0 || first.code == 3) << first.err;
    EXPECT_EQ(first.err, "");
    ASSERT_EQ(model_files(dir_ / "cache"), 1u);
    const std::string want = without_seconds(slurp(dir_ / "out1/result.json"));

    const Outcome second = run(dir_ / "job.yaml", dir_ / "out2");  // from the cache
    EXPECT_EQ(second.code, first.code);
    EXPECT_EQ(second.err, "");
    EXPECT_EQ(without_seconds(slurp(dir_ / "out2/result.json")), want);

    for (const auto& e : fs::directory_iterator(dir_ / "cache")) {
        std::string bytes = slurp(e.path());
        bytes[bytes.size() - 9] ^= 1;
        spit(e.path(), bytes);
    }
    const Outcome damaged = run(dir_ / "job.yaml", dir_ / "out3");
    EXPECT_EQ(damaged.code, first.code);
    EXPECT_NE(damaged.err.find("partloc: model cache: "), std::string::npos) << damaged.err;
    EXPECT_NE(damaged.err.find("checksum"), std::string::npos) << damaged.err;
    EXPECT_EQ(without_seconds(slurp(dir_ / "out3/result.json")), want);

    spit(dir_ / "a_file", "x");
    const Outcome unwritable =
        run(dir_ / "job.yaml", dir_ / "out4", "--cache '" + (dir_ / "a_file").string() + "'");
    EXPECT_EQ(unwritable.code, first.code);
    EXPECT_NE(unwritable.err.find("cannot keep box in the model cache"), std::string::npos) << unwritable.err;
    EXPECT_EQ(without_seconds(slurp(dir_ / "out4/result.json")), want);

    const Outcome named =
        run(dir_ / "job.yaml", dir_ / "out5", "--cache '" + (dir_ / "named").string() + "'");
    EXPECT_EQ(named.err, "");
    EXPECT_EQ(model_files(dir_ / "named"), 1u);
    EXPECT_EQ(without_seconds(slurp(dir_ / "out5/result.json")), want);

    fs::remove_all(dir_ / "cache");
    const Outcome none = run(dir_ / "job.yaml", dir_ / "out6", "--no-cache");
    EXPECT_EQ(none.err, "");
    EXPECT_FALSE(fs::exists(dir_ / "cache"));
    EXPECT_EQ(without_seconds(slurp(dir_ / "out6/result.json")), want);

    const Outcome both = run(dir_ / "job.yaml", dir_ / "out7", "--no-cache --cache '" + dir_.string() + "'");
    EXPECT_EQ(both.code, 2) << "--cache and --no-cache together";
}

TEST_F(CliRun, VersionPrintsTheProjectsVersionAndExitsZero) {
    const fs::path out_txt = dir_ / "version.txt";
    const int status =
        std::system(("'" + std::string(PARTLOC_EXE) + "' --version > '" + out_txt.string() + "'").c_str());
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 0);
    const std::string said = slurp(out_txt);
    EXPECT_EQ(said.rfind("partloc ", 0), 0u) << said;
    EXPECT_NE(said.find_first_of("0123456789"), std::string::npos) << said;
}

TEST_F(CliRun, ProgressTellsEachStageAndScanOnStderrAndQuietTellsNothing) {
    partloc::test::spit(dir_ / "job.yaml", job());
    const Outcome told = run(dir_ / "job.yaml", dir_ / "out1", "--progress");
    EXPECT_NE(told.err.find("partloc: registering 1 scans"), std::string::npos) << told.err;
    EXPECT_NE(told.err.find("partloc: scan 1 of 1 (scans/scan_01.ply"), std::string::npos) << told.err;
    const Outcome quiet = run(dir_ / "job.yaml", dir_ / "out2", "--quiet");
    EXPECT_EQ(quiet.err.find("partloc: registering"), std::string::npos) << quiet.err;
    EXPECT_EQ(told.code, quiet.code);
    // Not a terminal (here a file): nothing told unless asked.
    const Outcome plain = run(dir_ / "job.yaml", dir_ / "out3");
    EXPECT_EQ(plain.err.find("partloc: registering"), std::string::npos) << plain.err;
}
