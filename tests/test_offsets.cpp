// Work offsets for the controller (io/offsets.hpp, SPEC "Machining"): each file read back by a small reader
// written from the vendor's documentation, not from the writer, gives the placed frame to 1e-6 mm and
// 1e-6 degrees; what LinuxCNC cannot hold is stated as the error it really leaves at the far corner.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>
#include <sstream>

#include "partloc/core/format.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/offsets.hpp"
#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;
using partloc::io::OffsetDialect;

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

// Elementary rotations, written out (right-hand rule), so that the readers share nothing with the writer.
Eigen::Matrix3d Rx(double deg) {
    const double c = std::cos(deg * kDeg), s = std::sin(deg * kDeg);
    Eigen::Matrix3d R;
    R << 1, 0, 0, 0, c, -s, 0, s, c;
    return R;
}
Eigen::Matrix3d Ry(double deg) {
    const double c = std::cos(deg * kDeg), s = std::sin(deg * kDeg);
    Eigen::Matrix3d R;
    R << c, 0, s, 0, 1, 0, -s, 0, c;
    return R;
}
Eigen::Matrix3d Rz(double deg) {
    const double c = std::cos(deg * kDeg), s = std::sin(deg * kDeg);
    Eigen::Matrix3d R;
    R << c, -s, 0, s, c, 0, 0, 0, 1;
    return R;
}

Eigen::Isometry3d frame(const Eigen::Vector3d& origin, const Eigen::Matrix3d& R) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = R;
    T.translation() = origin;
    return T;
}

/// A frame read from a file: origin in mm, and the work offset number it names.
struct Read {
    Eigen::Isometry3d T_mm = Eigen::Isometry3d::Identity();
    int number = -1;
    bool ok = false;
};

/// Address words (letter + number) of an ISO G-code line, comments in parentheses removed.
std::map<std::string, double> words(const std::string& line) {
    std::string s;
    int depth = 0;
    for (char c : line) {
        if (c == '(')
            ++depth;
        else if (c == ')')
            --depth;
        else if (depth == 0)
            s += c;
    }
    std::map<std::string, double> w;
    static const std::regex word(R"(([A-Za-z])\s*([-+]?[0-9]*\.?[0-9]+))");
    for (auto it = std::sregex_iterator(s.begin(), s.end(), word); it != std::sregex_iterator(); ++it) {
        const std::string letter(1, static_cast<char>(std::toupper((*it)[1].str()[0])));
        const std::string key = w.count(letter) && letter == "G" ? "G" + std::to_string(w.size()) : letter;
        w[key] = std::stod((*it)[2]);
    }
    return w;
}

bool has_code(const std::string& line, const std::string& code) {
    const std::regex re("(^|\\s)" + code + "(\\s|$)");
    std::string s = line.substr(0, line.find('('));
    return std::regex_search(s, re);
}

std::vector<std::string> lines_of(const std::string& text) {
    std::vector<std::string> out;
    std::istringstream in(text);
    for (std::string l; std::getline(in, l);) out.push_back(l);
    return out;
}

/// Fanuc (30i descriptions §5.44): G10 L2 Pn X Y Z is workpiece offset n in machine coordinates; G68.2 X Y Z
/// I J K puts the feature coordinate system at X Y Z of the workpiece system, turned by the Euler angles:
/// I about Z, J about the new X, K about the new Z. G20 inch, G21 mm.
Read read_fanuc(const std::string& text) {
    Read r;
    double mm = 1.0;
    Eigen::Vector3d offset = Eigen::Vector3d::Zero(), feature = Eigen::Vector3d::Zero();
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    bool g10 = false, g682 = false;
    for (const auto& l : lines_of(text)) {
        if (has_code(l, "G20")) mm = 25.4;
        if (has_code(l, "G21")) mm = 1.0;
        auto w = words(l);
        if (has_code(l, "G10") && w.count("L") && w["L"] == 2) {
            offset = Eigen::Vector3d(w["X"], w["Y"], w["Z"]) * mm;
            r.number = static_cast<int>(w["P"]);
            g10 = true;
        }
        if (has_code(l, "G68.2")) {
            feature = Eigen::Vector3d(w["X"], w["Y"], w["Z"]) * mm;
            R = Rz(w["I"]) * Rx(w["J"]) * Rz(w["K"]);
            g682 = true;
        }
    }
    r.T_mm = frame(offset + feature, R);
    r.ok = g10 && g682;
    return r;
}

/// Siemens (K2 "Frames"): $P_UIFR[n] = CTRANS(X,x,Y,y,Z,z) : CROT(X,a,Y,b,Z,c); the translation first, the
/// rotation about the translated origin in RPY order Z, Y', X'' (about Z by c, the new Y by b, the newest X
/// by a). G700/G70 inch, G710/G71 mm.
Read read_siemens(const std::string& text) {
    Read r;
    double mm = 1.0;
    for (const auto& full : lines_of(text)) {
        const std::string l = full.substr(0, full.find(';'));
        if (has_code(l, "G70") || has_code(l, "G700")) mm = 25.4;
        if (has_code(l, "G71") || has_code(l, "G710")) mm = 1.0;
        std::smatch m;
        if (!std::regex_search(l, m, std::regex(R"(\$P_UIFR\[(\d+)\]\s*=\s*(.*))"))) continue;
        r.number = std::stoi(m[1]);
        const std::string rhs = m[2];
        std::map<std::string, std::map<char, double>> parts;  // function -> axis -> value
        static const std::regex fn(R"((CTRANS|CROT)\(([^)]*)\))");
        for (auto it = std::sregex_iterator(rhs.begin(), rhs.end(), fn); it != std::sregex_iterator(); ++it) {
            std::vector<std::string> args;
            std::stringstream ss((*it)[2].str());
            for (std::string a; std::getline(ss, a, ',');) args.push_back(a);
            for (std::size_t k = 0; k + 1 < args.size(); k += 2)
                parts[(*it)[1]][static_cast<char>(std::toupper(args[k].at(args[k].find_first_not_of(' '))))] =
                    std::stod(args[k + 1]);
        }
        auto& t = parts["CTRANS"];
        auto& q = parts["CROT"];
        r.T_mm = frame(Eigen::Vector3d(t['X'], t['Y'], t['Z']) * mm, Rz(q['Z']) * Ry(q['Y']) * Rx(q['X']));
        r.ok = true;
    }
    return r;
}

/// Heidenhain (preset table, PLANE SPATIAL): a preset row's X Y Z in machine coordinates, its 3D basic
/// rotation SPA SPB SPC spatial angles about the fixed machine axes, first A, then B, then C. The programme's
/// unit from BEGIN PGM ... MM / INCH.
Read read_heidenhain(const std::string& text) {
    Read r;
    double mm = 1.0;
    int q339 = -2;
    for (const auto& l : lines_of(text)) {
        if (std::regex_search(l, std::regex(R"(BEGIN PGM \S+ INCH)"))) mm = 25.4;
        std::smatch m;
        if (std::regex_search(l, m, std::regex(R"(Q339\s*=\s*\+?(\d+))"))) q339 = std::stoi(m[1]);
        if (l.find("PRESET NR=") == std::string::npos) continue;
        std::map<std::string, double> v;
        static const std::regex kv(R"(([A-Z]+)=([-+]?[0-9.]+))");
        for (auto it = std::sregex_iterator(l.begin(), l.end(), kv); it != std::sregex_iterator(); ++it)
            v[(*it)[1]] = std::stod((*it)[2]);
        r.number = static_cast<int>(v["NR"]);
        // About the fixed axes X, then Y, then Z: each later rotation multiplies from the left.
        const Eigen::Matrix3d R = Rz(v["SPC"]) * Ry(v["SPB"]) * Rx(v["SPA"]);
        r.T_mm = frame(Eigen::Vector3d(v["X"], v["Y"], v["Z"]) * mm, R);
        r.ok = true;
    }
    r.ok = r.ok && q339 == r.number;
    return r;
}

/// LinuxCNC (G10 L2): Pn's origin X Y Z in machine coordinates, R the rotation of XY about Z.
Read read_linuxcnc(const std::string& text) {
    Read r;
    double mm = 1.0;
    for (const auto& l : lines_of(text)) {
        if (has_code(l, "G20")) mm = 25.4;
        if (has_code(l, "G21")) mm = 1.0;
        auto w = words(l);
        if (has_code(l, "G10") && w.count("L") && w["L"] == 2) {
            r.number = static_cast<int>(w["P"]);
            r.T_mm = frame(Eigen::Vector3d(w["X"], w["Y"], w["Z"]) * mm, Rz(w.count("R") ? w["R"] : 0.0));
            r.ok = true;
        }
    }
    return r;
}

Read read_back(OffsetDialect d, const std::string& text) {
    switch (d) {
        case OffsetDialect::Fanuc:
            return read_fanuc(text);
        case OffsetDialect::Siemens:
            return read_siemens(text);
        case OffsetDialect::Heidenhain:
            return read_heidenhain(text);
        case OffsetDialect::LinuxCnc:
            return read_linuxcnc(text);
    }
    return {};
}

double rotation_deg(const Eigen::Matrix3d& A, const Eigen::Matrix3d& B) {
    return Eigen::AngleAxisd(A.transpose() * B).angle() / kDeg;
}

/// The error the file's comment states at the far corner (its own units).
double stated_error(const std::string& text) {
    std::smatch m;
    if (!std::regex_search(text, m,
                           std::regex(R"(error at the part's far corner \[[^\]]*\] \w+: ([0-9.]+))")))
        return -1;
    return std::stod(m[1]);
}

const OffsetDialect kAll[] = {OffsetDialect::Fanuc, OffsetDialect::Siemens, OffsetDialect::Heidenhain,
                              OffsetDialect::LinuxCnc};

/// Random frames and the hard ones: near gimbal lock of XYZ (b = ±90) and of ZXZ (square, upside down),
/// angles near ±180.
std::vector<Eigen::Isometry3d> frames() {
    std::vector<Eigen::Isometry3d> out;
    std::mt19937 rng(26);
    std::uniform_real_distribution<double> pos(-900, 900), ang(-180, 180);
    for (int i = 0; i < 40; ++i)
        out.push_back(frame(Eigen::Vector3d(pos(rng), pos(rng), pos(rng)),
                            Rz(ang(rng)) * Ry(ang(rng) / 2) * Rx(ang(rng))));
    const double special[][3] = {
        {0, 0, 0},        {0.3, -0.2, 0.1},      {0, 90, 0},        {10, 89.9999999, -20}, {5, -90, 30},
        {179.9999, 0, 0}, {-179.9999, 0.5, 180}, {180, 0, 0},       {0, 0, 180},           {0, 0, -179.99999},
        {90, 0, 90},      {-90, 45, -90},        {0.0000001, 0, 0}, {180, 1e-7, -1e-7}};
    for (const auto& e : special)
        out.push_back(frame(Eigen::Vector3d(pos(rng), pos(rng), pos(rng)), Rz(e[2]) * Ry(e[1]) * Rx(e[0])));
    return out;
}

}  // namespace

TEST(Offsets, EachDialectReadBackGivesThePlacedFrame) {
    for (bool inch : {false, true}) {
        io::OffsetSettings s;
        s.work_offset = inch ? 6 : 2;
        s.inch = inch;
        s.far_corner = Eigen::Vector3d(180, -40, 60);
        for (const auto& T_mm : frames()) {
            Eigen::Isometry3d T = T_mm;
            if (inch) T.translation() /= 25.4;
            const bool about_z_only = std::abs(T.linear()(2, 2) - 1.0) < 1e-15;
            for (OffsetDialect d : kAll) {
                const io::WorkOffsetFile f = io::write_work_offset(d, T, s);
                const Read r = read_back(d, f.text);
                ASSERT_TRUE(r.ok) << io::dialect_name(d) << "\n" << f.text;
                EXPECT_EQ(r.number, s.work_offset) << io::dialect_name(d);
                EXPECT_LT((r.T_mm.translation() - T_mm.translation()).norm(), 1e-6)
                    << io::dialect_name(d) << "\n"
                    << f.text;
                if (d == OffsetDialect::LinuxCnc && !about_z_only) continue;
                EXPECT_LT(rotation_deg(r.T_mm.linear(), T_mm.linear()), 1e-6) << io::dialect_name(d) << "\n"
                                                                              << f.text;
            }
        }
    }
}

TEST(Offsets, LinuxCncStatesTheErrorItLeavesAtTheFarCorner) {
    io::OffsetSettings s;
    s.far_corner = Eigen::Vector3d(250, 120, -80);
    int tilted = 0;
    for (const auto& T : frames()) {
        const io::WorkOffsetFile f = io::write_work_offset(OffsetDialect::LinuxCnc, T, s);
        const Read r = read_back(OffsetDialect::LinuxCnc, f.text);
        ASSERT_TRUE(r.ok);
        const double real = (r.T_mm * s.far_corner - T * s.far_corner).norm();
        EXPECT_NEAR(f.error_at_far_corner, real, 1e-6);
        EXPECT_NEAR(stated_error(f.text), real, 1e-6) << f.text;
        // The rotation about Z written is the nearest: no other R leaves a smaller rotation.
        const double left = rotation_deg(r.T_mm.linear(), T.linear());
        for (double dz : {-0.01, 0.01}) {
            const Eigen::Matrix3d other = Rz(dz) * r.T_mm.linear();
            EXPECT_GE(rotation_deg(other, T.linear()), left - 1e-9);
        }
        if (real > 1e-3) {
            ++tilted;
            EXPECT_NE(f.cannot_represent.find("about Z only"), std::string::npos);
        }
    }
    EXPECT_GT(tilted, 30);
}

TEST(Offsets, FanucSaysWhatTheOffsetAloneLeaves) {
    io::OffsetSettings s;
    s.far_corner = Eigen::Vector3d(100, 0, 0);
    const Eigen::Isometry3d T = frame(Eigen::Vector3d(10, 20, 30), Rz(1.0));
    const io::WorkOffsetFile f = io::write_work_offset(OffsetDialect::Fanuc, T, s);
    // G10 L2 without G68.2: the far corner 100 mm out, turned by 1 degree, is 2 * 100 * sin(0.5 deg) off.
    const std::string want = partloc::format("%.6f", 200 * std::sin(0.5 * kDeg));
    EXPECT_NE(f.cannot_represent.find(want), std::string::npos) << f.cannot_represent;
    EXPECT_LT(f.error_at_far_corner, 1e-6);
}

TEST(Offsets, RotaryAxisSquaresThePart) {
    Axis a;
    a.name = "A";
    a.type = AxisType::Rotary;
    a.direction = Eigen::Vector3d::UnitX();
    a.point = Eigen::Vector3d(0, 10, -20);
    const Eigen::Isometry3d nominal = frame(Eigen::Vector3d(-76, -12, 20), Rz(90));
    // Turned about A by 5.04 degrees and tilted a little about Y and Z: A = -5.04 (nearly) squares it.
    const Eigen::Matrix3d turn = Rz(0.23) * Ry(-0.42) * Rx(5.04);
    const Eigen::Isometry3d located = frame(Eigen::Vector3d(-75, -13, 21), turn * nominal.linear());
    const io::RotaryAxisSquaring r = io::square_with_axis(a, located, nominal);
    EXPECT_NEAR(r.value_deg, -5.04, 0.01);
    EXPECT_NEAR(r.tilt_left_deg.dot(a.direction), 0.0, 1e-9);  // nothing left about the axis itself
    const Eigen::Matrix3d R_dev = located.linear() * nominal.linear().transpose();
    const double left = Eigen::AngleAxisd(Rx(r.value_deg) * R_dev).angle() / kDeg;
    EXPECT_NEAR(left, r.tilt_left_angle_deg, 1e-9);
    for (double d : {-0.01, 0.01})
        EXPECT_GT(Eigen::AngleAxisd(Rx(r.value_deg + d) * R_dev).angle() / kDeg, left);
    EXPECT_NEAR(r.tilt_left_angle_deg, std::hypot(0.42, 0.23), 0.01);
    // A pure turn about A is squared exactly.
    const Eigen::Isometry3d turned = a.motion(7.5) * nominal;
    const io::RotaryAxisSquaring t = io::square_with_axis(a, turned, nominal);
    EXPECT_NEAR(t.value_deg, -7.5, 1e-9);
    EXPECT_LT(t.tilt_left_angle_deg, 1e-9);
    EXPECT_LT((t.T_machine_workpiece_at_value.translation() - nominal.translation()).norm(), 1e-9);
}

TEST(Offsets, RunWritesTheFilesOfResultJsonsPose) {
    test::TempFolder tmp("partloc_offsets");
    const fs::path cell = tmp.dir / "cell", out = tmp.dir / "out", log = tmp.dir / "log.txt";
    const auto sh = [](const std::string& cmd) {
        const int status = std::system(cmd.c_str());
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    };
    ASSERT_EQ(sh("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1"), 0);
    test::spit(cell / "job.yaml",
               test::slurp(cell / "job.yaml") +
                   "\noutput: {offsets: [fanuc, siemens, heidenhain, linuxcnc], work_offset: 2}\n");
    // The final part placed (translations, within 0.5): the offsets are the placed frame (SPEC "Machining").
    test::spit(cell / "job.yaml",
               std::regex_replace(test::slurp(cell / "job.yaml"), std::regex("\n  final_part: ([^\n]*)"),
                                  "\n  final_part: $1\n  placement: {mode: maxmin, free: [x, y, z], limits: "
                                  "{translation: 0.5}}"));
    ASSERT_EQ(sh("PARTLOC_CACHE='" + (tmp.dir / "cache").string() + "' '" PARTLOC_EXE "' run '" +
                 (cell / "job.yaml").string() + "' --out '" + out.string() + "' --threads 2 > '" +
                 log.string() + "' 2>&1"),
              0)
        << test::slurp(log);
    const auto result = nlohmann::json::parse(test::slurp(out / "result.json"));
    ASSERT_EQ(result["status"], "located");
    const double mm = partloc::millimetres_per_unit(result["units"].get<std::string>());
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
            T.matrix()(r, c) = result["placement"]["T_machine_part"][r][c].get<double>();
    T.translation() *= mm;
    ASSERT_EQ(result["placement"]["mode"], "maxmin") << result["placement"].dump();
    EXPECT_LE(result["placement"]["moved_from_located"]["translation"].get<double>(), 0.5 + 1e-9);
    EXPECT_NEAR(result["placement"]["moved_from_located"]["rotation_deg"].get<double>(), 0.0, 1e-9);
    EXPECT_GE(result["placement"]["min_allowance"].get<double>(),
              result["allowance"]["located_min"].get<double>());
    EXPECT_TRUE(fs::exists(out / "allowance.ply"));
    EXPECT_TRUE(fs::exists(out / "final_part_placed.stl"));
    // The models for CAM in the frame the offsets give (issue 26). The final part there is its CAD in the
    // job's nominal datum frame whatever the location and the placement (both move the frame and the part
    // together): a known answer. The stock is stock.stl carried by the inverse of that frame.
    {
        const Job job = io::load_job(cell / "job.yaml");
        ASSERT_TRUE(job.workpiece.final_part && job.workpiece.final_part->mesh);
        ASSERT_EQ(result["cam"]["frame"], "placement.T_machine_part");
        ASSERT_EQ(result["cam"]["final_part"], "cam/final_part.stl");
        const auto cam_part = io::read_mesh(out / "cam" / "final_part.stl", "cam part");
        const auto& cad = *job.workpiece.final_part->mesh;
        const Eigen::Isometry3d T_nominal_inv = job.workpiece.T_machine_workpiece.inverse();
        ASSERT_EQ(cam_part->triangles_.size(), cad.triangles_.size());
        double worst = 0.0;
        for (std::size_t t = 0; t < cad.triangles_.size(); ++t)
            for (int k = 0; k < 3; ++k) {
                const Eigen::Vector3d want = T_nominal_inv * cad.vertices_[cad.triangles_[t][k]];
                double best = 1e300;  // STL merges corners: compare with the nearest corner of triangle t
                for (int q = 0; q < 3; ++q)
                    best = std::min(best, (cam_part->vertices_[cam_part->triangles_[t][q]] - want).norm());
                worst = std::max(worst, best);
            }
        EXPECT_LT(worst, 1e-3) << "cam/final_part.stl is not the CAD in the nominal workpiece frame";
        const auto stock = io::read_mesh(out / "stock.stl", "stock");
        const auto cam_stock = io::read_mesh(out / "cam" / "stock.stl", "cam stock");
        ASSERT_EQ(cam_stock->vertices_.size(), stock->vertices_.size());
        Eigen::Isometry3d T_units = T;  // the files are in the job's units, as result.json
        T_units.translation() /= mm;
        const Eigen::Isometry3d T_part_machine = T_units.inverse();
        double stock_worst = 0.0;
        for (std::size_t v = 0; v < stock->vertices_.size(); ++v)
            stock_worst = std::max(stock_worst,
                                   (cam_stock->vertices_[v] - T_part_machine * stock->vertices_[v]).norm());
        EXPECT_LT(stock_worst, 1e-3);
    }
    const auto& offsets = result["offsets"];
    ASSERT_TRUE(offsets["written"].get<bool>()) << offsets.dump();
    EXPECT_EQ(offsets["work_offset"], 2);
    Eigen::Vector3d corner;
    for (int k = 0; k < 3; ++k) corner[k] = offsets["far_corner"][k].get<double>() * mm;
    EXPECT_GT(corner.norm(), 1.0);
    for (OffsetDialect d : kAll) {
        const auto& entry = offsets["files"][io::dialect_name(d)];
        ASSERT_EQ(entry["file"], "offsets/" + io::dialect_file(d)) << offsets.dump();
        const std::string text = test::slurp(out / "offsets" / io::dialect_file(d));
        const Read r = read_back(d, text);
        ASSERT_TRUE(r.ok) << text;
        EXPECT_EQ(r.number, 2);
        EXPECT_LT((r.T_mm.translation() - T.translation()).norm(), 1e-6) << text;
        const double real = (r.T_mm * corner - T * corner).norm();
        EXPECT_NEAR(entry["error_at_far_corner"].get<double>() * mm, real, 1e-6) << io::dialect_name(d);
        if (d != OffsetDialect::LinuxCnc) {
            EXPECT_LT(rotation_deg(r.T_mm.linear(), T.linear()), 1e-6) << text;
        }
    }
    // Without the workpiece located there are no files (those of the run before are removed), and
    // result.json says so: the same job with its region where the part is not.
    test::spit(cell / "job2.yaml",
               std::regex_replace(test::slurp(cell / "job.yaml"), std::regex("  region: \\{[^\n]*\\}"),
                                  "  region: {min: [5000, 5000, 5000], max: [5001, 5001, 5001]}"));
    const int code = sh("PARTLOC_CACHE='" + (tmp.dir / "cache").string() + "' '" PARTLOC_EXE "' run '" +
                        (cell / "job2.yaml").string() + "' --out '" + out.string() + "' --threads 2 > '" +
                        log.string() + "' 2>&1");
    ASSERT_EQ(code, 3) << test::slurp(log);
    const auto failed = nlohmann::json::parse(test::slurp(out / "result.json"));
    EXPECT_FALSE(failed["offsets"]["written"].get<bool>());
    EXPECT_NE(failed["offsets"]["message"].get<std::string>().find("not located"), std::string::npos);
    for (OffsetDialect d : kAll) EXPECT_FALSE(fs::exists(out / "offsets" / io::dialect_file(d)));
    EXPECT_FALSE(fs::exists(out / "cam" / "final_part.stl"));
    EXPECT_FALSE(fs::exists(out / "cam" / "stock.stl"));
    EXPECT_FALSE(failed.contains("cam"));
}

TEST(Offsets, JobFieldsAreChecked) {
    test::TempFolder tmp("partloc_offsets_job");
    const fs::path cell = tmp.dir / "cell";
    ASSERT_EQ(
        std::system(
            ("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1").c_str()),
        0);
    const std::string job = test::slurp(cell / "job.yaml");
    test::spit(cell / "a.yaml", job + "\noutput: {offsets: [fanuc, mazak]}\n");
    test::expect_job_error(cell / "a.yaml", "output.offsets[1]: unknown dialect 'mazak'");
    test::spit(cell / "b.yaml", job + "\noutput: {offsets: [fanuc], work_offset: 7}\n");
    test::expect_job_error(cell / "b.yaml", "output.work_offset: must be a whole number from 1");
    test::spit(cell / "c.yaml", job + "\noutput: {offsets: [fanuc], work_offset: 1.5}\n");
    test::expect_job_error(cell / "c.yaml", "output.work_offset");
    test::spit(cell / "d.yaml", job + "\noutput: {offset: [fanuc]}\n");
    test::expect_job_error(cell / "d.yaml", "output.offset: unknown field");
    test::spit(cell / "e.yaml", job + "\noutput: {offsets: [siemens, linuxcnc], work_offset: 6}\n");
    const Job j = io::load_job(cell / "e.yaml");
    EXPECT_EQ(j.output.offsets, (std::vector<std::string>{"siemens", "linuxcnc"}));
    EXPECT_EQ(j.output.work_offset, 6);
}

TEST(Machining, JobFieldsAreChecked) {
    test::TempFolder tmp("partloc_machining_job");
    const fs::path cell = tmp.dir / "cell";
    ASSERT_EQ(
        std::system(
            ("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1").c_str()),
        0);
    const std::string job = test::slurp(cell / "job.yaml");
    const auto with = [&](const std::string& name, const std::string& fields) {
        test::spit(cell / name, std::regex_replace(job, std::regex("\n  final_part: ([^\n]*)"),
                                                   "\n  final_part: $1\n" + fields));
        return cell / name;
    };
    test::expect_job_error(with("a.yaml", "  placement: {mode: best}"),
                           "workpiece.placement.mode: expected located or maxmin, found 'best'");
    test::expect_job_error(with("b.yaml", "  placement: {mode: maxmin, free: [x, q]}"),
                           "workpiece.placement.free[1]: expected one of x, y, z, a, b, c, found 'q'");
    test::expect_job_error(with("c.yaml", "  placement: {mode: maxmin, limits: {translation: -1}}"),
                           "workpiece.placement.limits.translation: must be at least 0");
    test::expect_job_error(with("d.yaml", "  allowance: {least: 1}"),
                           "workpiece.allowance.least: unknown field");
    test::spit(cell / "e.yaml", std::regex_replace(job, std::regex("\n  final_part: [^\n]*"),
                                                   "\n  placement: {mode: maxmin}"));
    test::expect_job_error(cell / "e.yaml", "workpiece.placement: maxmin needs workpiece.final_part");
    const Job j =
        io::load_job(with("f.yaml",
                          "  allowance: {min: 0.25}\n  placement: {mode: maxmin, free: [z, A], limits: "
                          "{translation: 1.5, rotation_deg: 0.5}}"));
    EXPECT_EQ(j.workpiece.allowance_min, 0.25);
    EXPECT_TRUE(j.workpiece.placement.maxmin);
    EXPECT_EQ(j.workpiece.placement.free, (std::array<bool, 6>{false, false, true, true, false, false}));
    EXPECT_EQ(j.workpiece.placement.max_translation, 1.5);
    EXPECT_EQ(j.workpiece.placement.max_rotation_deg, 0.5);
    const Job plain = io::load_job(cell / "job.yaml");
    EXPECT_FALSE(plain.workpiece.placement.maxmin);
    EXPECT_FALSE(plain.workpiece.allowance_min.has_value());
}

TEST(Offsets, JobUnitsBecomeMillimetresOrInchesAndTheFarCornerIsTheBoxes) {
    // A part 200 x 100 x 50 mm, given in metres, its datum frame at (10, 0, 0) m turned 90 degrees about Z.
    const Eigen::Isometry3d nominal = frame(Eigen::Vector3d(10, 0, 0), Rz(90));
    auto part = std::make_shared<open3d::geometry::TriangleMesh>();
    for (int i = 0; i < 8; ++i)
        part->vertices_.push_back(nominal *
                                  Eigen::Vector3d(0.2 * (i & 1), 0.1 * ((i >> 1) & 1), 0.05 * (i >> 2)));
    part->triangles_.push_back({0, 1, 2});
    for (const std::string units : {"m", "in"}) {
        Job job;
        job.units = units;
        job.workpiece.T_machine_workpiece = nominal;
        job.workpiece.final_part = ModelSource{"part.stl", part, nullptr};
        job.output.offsets = {"fanuc", "linuxcnc"};
        job.output.work_offset = 3;
        JobResult result;
        result.units = units;
        result.workpiece.valid = true;
        result.workpiece.T_machine_workpiece_nominal = nominal;
        result.workpiece.T_machine_workpiece =
            frame(Eigen::Vector3d(10.001, 0.002, -0.001), Rx(0.5) * Rz(90.2));
        const io::WorkOffsets w = io::work_offsets(job, result);
        ASSERT_TRUE(w.written);
        EXPECT_EQ(w.units, units == "in" ? "in" : "mm");
        EXPECT_LT((w.far_corner - Eigen::Vector3d(0.2, 0.1, 0.05)).norm(), 1e-12) << w.far_corner.transpose();
        ASSERT_EQ(w.files.size(), 2u);
        const double mm = units == "in" ? 25.4 : 1000.0;  // millimetres per job unit
        Eigen::Isometry3d T_mm = result.workpiece.T_machine_workpiece;
        T_mm.translation() *= mm;
        const Eigen::Vector3d corner_mm = w.far_corner * mm;
        for (const auto& f : w.files) {
            const Read r = read_back(f.dialect, f.text);
            ASSERT_TRUE(r.ok) << f.text;
            EXPECT_EQ(r.number, 3);
            EXPECT_LT((r.T_mm.translation() - T_mm.translation()).norm(), 1e-6) << f.text;
            const double real_mm = (r.T_mm * corner_mm - T_mm * corner_mm).norm();
            EXPECT_NEAR(f.error_at_far_corner * (units == "in" ? 25.4 : 1.0), real_mm, 1e-6) << f.text;
        }
        // result.json's numbers are in the job's units.
        const auto j = nlohmann::json::parse(io::work_offsets_json(job, result));
        EXPECT_NEAR(
            j["files"]["linuxcnc"]["error_at_far_corner"].get<double>() * mm,
            (read_back(OffsetDialect::LinuxCnc, w.files[1].text).T_mm * corner_mm - T_mm * corner_mm).norm(),
            1e-6);
        EXPECT_NEAR(j["far_corner"][0].get<double>(), 0.2, 1e-9);
    }
}
