// The job's own checks (pipeline/job_checks.hpp) and `partloc check` (issue 27): scans in other units than
// the job says are named with the unit they would fit, and correct jobs draw no warning.
#include <gtest/gtest.h>
#include <open3d/io/TriangleMeshIO.h>

#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <regex>

#include "partloc/io/cloud_io.hpp"
#include "partloc/pipeline/job_checks.hpp"
#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scenario.hpp"
#include "partloc/sim/shapes.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;

namespace {

/// Two threads, no stock: what these checks need of a run.
RunSettings quick_settings() {
    RunSettings settings;
    settings.threads = 2;
    settings.build_stock = false;
    return settings;
}

/// The job with every scan's coordinates multiplied by k, as if its files were written in another unit.
Job scaled_scans(Job job, double k) {
    for (Scan& s : job.scans) {
        auto c = std::make_shared<open3d::geometry::PointCloud>(*s.points);
        for (auto& p : c->points_) p *= k;
        s.points = c;
    }
    return job;
}

}  // namespace

TEST(JobChecks, ScansInOtherUnitsAreNamedAndCorrectJobsAreNot) {
    for (std::uint64_t seed : {3u, 11u}) {
        const sim::SimulatedJob s = sim::simulate_random_cell(seed);
        EXPECT_TRUE(unit_warnings(s.job, summarise_scans(s.job)).empty()) << "seed " << seed;
        const struct {
            double k;
            const char* unit;
        } cases[] = {{0.001, "units: m"}, {1 / 25.4, "units: in"}, {1000.0, "units: um"}};
        // (A factor of 10, cm for mm, leaves a scan of a few fiducials' size: not told from a close view.)
        for (const auto& c : cases) {
            const Job job = scaled_scans(s.job, c.k);
            const std::vector<std::string> w = unit_warnings(job, summarise_scans(job));
            ASSERT_EQ(w.size(), job.scans.size())
                << "seed " << seed << ", scans x " << c.k << ": " << (w.empty() ? "" : w[0]);
            EXPECT_NE(w[0].find(job.scans[0].file), std::string::npos) << w[0];
            EXPECT_NE(w[0].find(std::string("did you mean ") + c.unit), std::string::npos) << w[0];
        }
    }
}

TEST(JobChecks, CheckPrintsTheJobAndRunWarnsOfTheUnits) {
    test::TempFolder tmp("partloc_check");
    const fs::path cell = tmp.dir / "cell", log = tmp.dir / "log.txt";
    ASSERT_EQ(
        test::shell("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1"), 0);
    ASSERT_EQ(test::shell("'" PARTLOC_EXE "' check '" + (cell / "job.yaml").string() + "' > '" +
                          log.string() + "' 2>&1"),
              0)
        << test::slurp(log);
    const std::string good = test::slurp(log);
    EXPECT_NE(good.find("scans: 6"), std::string::npos) << good;
    EXPECT_NE(good.find("fiducials: "), std::string::npos) << good;
    EXPECT_NE(good.find("units: mm"), std::string::npos) << good;
    EXPECT_NE(good.find("warnings: none"), std::string::npos) << good;

    // The scans written in metres, the job saying nothing of it.
    const std::string job = test::slurp(cell / "job.yaml");
    std::smatch m;
    std::string edited = job;
    for (int i = 1; i <= 6; ++i) {
        char name[32];
        std::snprintf(name, sizeof name, "scans/scan_%02d.ply", i);
        const auto c = io::read_point_cloud(cell / name, name);
        for (auto& p : c->points_) p *= 0.001;
        char metres[32];
        std::snprintf(metres, sizeof metres, "scans/scan_%02d_m.ply", i);
        io::write_point_cloud(cell / metres, *c);
        edited = std::regex_replace(edited, std::regex(name), metres);
    }
    ASSERT_NE(edited, job);
    test::spit(cell / "metres.yaml", edited);
    ASSERT_EQ(test::shell("'" PARTLOC_EXE "' check '" + (cell / "metres.yaml").string() + "' > '" +
                          log.string() + "' 2>&1"),
              0);
    const std::string bad = test::slurp(log);
    EXPECT_NE(bad.find("warnings: 6"), std::string::npos) << bad;
    EXPECT_NE(bad.find("did you mean units: m"), std::string::npos) << bad;
    // `run` says the same in result.json's warnings (whatever it registers).
    const fs::path out = tmp.dir / "out";
    test::shell("PARTLOC_CACHE='" + (tmp.dir / "cache").string() + "' '" PARTLOC_EXE "' run '" +
                (cell / "metres.yaml").string() + "' --out '" + out.string() + "' --threads 2 > '" +
                log.string() + "' 2>&1");
    const auto result = nlohmann::json::parse(test::slurp(out / "result.json"));
    int named = 0;
    for (const auto& w : result["warnings"])
        named += w.get<std::string>().find("did you mean units: m") != std::string::npos;
    EXPECT_EQ(named, 6) << result["warnings"].dump();

    // A job that cannot be read: exit 2, one line naming the file.
    test::spit(cell / "broken.yaml",
               std::regex_replace(job, std::regex("scans/scan_01.ply"), "scans/none.ply"));
    ASSERT_EQ(test::shell("'" PARTLOC_EXE "' check '" + (cell / "broken.yaml").string() + "' > '" +
                          log.string() + "' 2>&1"),
              2);
    const std::string refused = test::slurp(log);
    EXPECT_NE(refused.find("none.ply"), std::string::npos) << refused;
    EXPECT_EQ(std::count(refused.begin(), refused.end(), '\n'), 1) << refused;
}

// A fiducial that maps onto itself by a turn (issue 25: symmetric fiducials) is named when the job is read:
// it cannot place a scan alone. The simulated blocks, of no symmetry, are not.
TEST(JobChecks, ASymmetricFiducialIsNamedWhenTheJobIsRead) {
    test::TempFolder tmp("partloc_symmetric");
    const fs::path cell = tmp.dir / "cell", log = tmp.dir / "log.txt";
    ASSERT_EQ(
        test::shell("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1"), 0);
    sim::HeightField box;
    box.x_edges = {0, 15, 45, 60};
    box.y_edges = {0, 30};
    box.top = {20, 30, 20};
    ASSERT_TRUE(open3d::io::WriteTriangleMesh((cell / "models" / "fiducial_B.stl").string(),
                                              *sim::make_height_field_block(box)));
    ASSERT_EQ(test::shell("'" PARTLOC_EXE "' check '" + (cell / "job.yaml").string() + "' > '" +
                          log.string() + "' 2>&1"),
              0)
        << test::slurp(log);
    const std::string said = test::slurp(log);
    EXPECT_NE(said.find("warnings: 1\n"), std::string::npos) << said;
    EXPECT_NE(
        said.find("fiducial B cannot place a scan alone: it maps onto itself turned 180 deg about (0, 0, 1)"),
        std::string::npos)
        << said;
}

// The finished part's faces given as the reference surfaces (issue 27's first mistake): located off by
// the allowance with a tight interval, unless the check names the faces the scans show elsewhere.
TEST(JobChecks, FinishedFacesGivenAsTheReferenceAreNamed) {
    const sim::SimulatedJob s = sim::simulate_random_cell(106);
    const RunSettings settings = quick_settings();
    const auto named = [](const JobResult& r) {
        int n = 0;
        for (const std::string& w : r.warnings)
            n += w.find("are the reference surfaces the as-built faces?") != std::string::npos;
        return n;
    };
    const JobResult right = run_job(s.job, settings);
    ASSERT_TRUE(right.workpiece.valid) << right.workpiece.reason;
    EXPECT_EQ(named(right), 0);
    Job wrong = s.job;
    ASSERT_TRUE(wrong.workpiece.final_part);
    wrong.workpiece.reference_surfaces = *wrong.workpiece.final_part;
    const JobResult r = run_job(wrong, settings);
    EXPECT_GE(named(r), 1);
    for (const std::string& w : r.warnings)
        if (w.find("as-built faces?") != std::string::npos) {
            EXPECT_EQ(w.rfind("workpiece.reference_surfaces: the scans lie ", 0), 0u) << w;
            std::smatch m;  // by the sim's allowance, 1.0 mm
            ASSERT_TRUE(std::regex_search(w, m, std::regex("lie ([0-9.]+) mm inside"))) << w;
            EXPECT_NEAR(std::stod(m[1].str()), 1.0, 0.05) << w;
        }
}

// `axes:` left out of the rotated scans (issue 27's second mistake): seed 106's scans at A = 45 and 90
// degrees told as if at 0. Each is named with the axis and the value it was taken at, left out of the part,
// and the part located from the scans at 0 as right as with the axes given; with the axes given, none is
// named.
TEST(JobChecks, ScansAtOtherAxisPositionsWithoutAxesAreNamed) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const sim::SimulatedJob s = sim::simulate_random_cell(106);
    const RunSettings settings = quick_settings();
    const auto turned = [](const JobResult& r) {
        int n = 0;
        for (const std::string& w : r.warnings) n += w.find("about axis A") != std::string::npos;
        return n;
    };
    const JobResult right = run_job(s.job, settings);
    ASSERT_TRUE(right.workpiece.valid) << right.workpiece.reason;
    EXPECT_EQ(turned(right), 0);
    Job wrong = s.job;
    std::vector<double> taken_at;
    for (Scan& scan : wrong.scans) {
        taken_at.push_back(scan.axes.count("A") ? scan.axes.at("A") : 0.0);
        scan.axes.clear();
    }
    ASSERT_GT(std::count_if(taken_at.begin(), taken_at.end(), [](double a) { return a != 0.0; }), 1);
    const JobResult r = run_job(wrong, settings);
    ASSERT_TRUE(r.workpiece.valid) << r.workpiece.reason;
    EXPECT_LT(pose_error(r.workpiece.T_machine_workpiece, s.truth.T_machine_workpiece).translation, 0.05);
    int named = 0;
    for (std::size_t i = 0; i < r.scans.size(); ++i) {
        const ScanResult& sc = r.scans[i];
        std::smatch m;
        const bool told = std::regex_search(sc.reason, m, std::regex("axes: \\{A: (-?[0-9.]+)\\}"));
        if (taken_at[i] == 0.0) {
            EXPECT_FALSE(told) << sc.file << ": " << sc.reason;
            continue;
        }
        // A registered scan at another position is named; one rejected before the part was for its own
        // reason.
        if (!right.scans[i].valid) continue;
        ASSERT_TRUE(told) << sc.file << " (A = " << taken_at[i] << "): " << sc.reason;
        EXPECT_FALSE(sc.valid);
        EXPECT_NEAR(std::stod(m[1].str()), taken_at[i], 0.2) << sc.reason;
        ++named;
    }
    EXPECT_GT(named, 1);
    EXPECT_EQ(turned(r), named);
}

namespace {

/// The job with the workpiece's points of the scans in `moved` displaced by `shift` (scan frame), as if
/// the part had moved in its clamp before those scans were taken; the fiducials' points stay.
Job part_moved_in(const sim::SimulatedJob& s, const std::vector<std::size_t>& moved,
                  const Eigen::Vector3d& shift) {
    Job job = s.job;
    const int workpiece = s.cell.find("workpiece");
    for (std::size_t i : moved) {
        auto c = std::make_shared<open3d::geometry::PointCloud>(*job.scans[i].points);
        for (std::size_t k = 0; k < c->points_.size(); ++k)
            if (s.scans[i].body[k] == workpiece) c->points_[k] += shift;
        job.scans[i].points = c;
    }
    return job;
}

}  // namespace

// Scans that show the part in different places (it moved in its clamp, or a scan at A = 90 given without its
// axes registered by both fiducials as at 0: seed 8 located 1.56 mm off): a minority left out with the
// reason, the part located from the rest; where they do not outnumber the others, not located.
TEST(JobChecks, ScansThatShowThePartElsewhereAreLeftOutOrTheRunRefuses) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const sim::SimulatedJob s = sim::simulate_random_cell(106);
    const RunSettings settings = quick_settings();
    const JobResult right = run_job(s.job, settings);
    ASSERT_TRUE(right.workpiece.valid) << right.workpiece.reason;
    const auto left_out = [](const JobResult& r) {
        std::vector<std::size_t> out;
        for (std::size_t i = 0; i < r.scans.size(); ++i)
            if (r.scans[i].reason.find("fitted on its own points") != std::string::npos) out.push_back(i);
        return out;
    };
    EXPECT_TRUE(left_out(right).empty());
    std::vector<std::size_t> registered;
    for (std::size_t i = 0; i < right.scans.size(); ++i)
        if (right.scans[i].valid) registered.push_back(i);
    ASSERT_GE(registered.size(), 4u);

    // One scan's part 1 mm off: left out, named, and the part located from the others as before.
    const Eigen::Vector3d shift = Eigen::Vector3d(1.0, 1.0, 1.0).normalized();
    const JobResult one = run_job(part_moved_in(s, {registered[1]}, shift), settings);
    ASSERT_TRUE(one.workpiece.valid) << one.workpiece.reason;
    // Left out of the part, by the turned-scan check (a shift reads as a small turn about A) or by the part
    // check; the others not.
    for (std::size_t i = 0; i < one.scans.size(); ++i)
        EXPECT_EQ(one.scans[i].valid, right.scans[i].valid && i != registered[1]) << one.scans[i].reason;
    EXPECT_LT(pose_error(one.workpiece.T_machine_workpiece, s.truth.T_machine_workpiece).translation, 0.05);

    // Half the scans' part 2 mm off: the part fitted between them takes the most-off scans out one by one
    // (measured: two of the three, the third confirms no part at all), and where the rest do not outnumber
    // them, nothing says which is right. Never a part between the two.
    const std::vector<std::size_t> half(registered.begin(), registered.begin() + registered.size() / 2);
    const JobResult split = run_job(part_moved_in(s, half, 2.0 * shift), settings);
    const std::vector<std::size_t> named = left_out(split);
    for (std::size_t i : named) EXPECT_NE(std::find(half.begin(), half.end(), i), half.end()) << i;
    if (split.workpiece.valid) {
        EXPECT_FALSE(named.empty());
        EXPECT_LT(pose_error(split.workpiece.T_machine_workpiece, s.truth.T_machine_workpiece).translation,
                  0.05);
    } else {
        EXPECT_NE(split.workpiece.reason.find("the scans do not show one part"), std::string::npos)
            << split.workpiece.reason;
    }
}

// The mistake of issue 27's table on seed 8: with `axes` left out, a scan at A = 90 registered by both
// fiducials as at 0 and the part was located 1.56 mm off, between it and a scan at 0. Now not located.
TEST(JobChecks, SeedEightWithoutAxesIsNotLocatedWrong) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const sim::SimulatedJob s = sim::simulate_random_cell(8);
    const RunSettings settings = quick_settings();
    Job wrong = s.job;
    for (Scan& scan : wrong.scans) scan.axes.clear();
    const JobResult r = run_job(wrong, settings);
    EXPECT_FALSE(r.workpiece.valid);
    EXPECT_NE(r.workpiece.reason.find("the scans do not show one part"), std::string::npos)
        << r.workpiece.reason;
}
