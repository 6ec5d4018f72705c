#include "partloc/io/offsets.hpp"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <sstream>

#include "partloc/core/format.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/io/atomic_file.hpp"

namespace partloc::io {

namespace fs = std::filesystem;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

// Decimals written: enough that the file gives the frame back to 1e-6 mm and 1e-6 degrees. A control takes
// fewer (Fanuc IS-B 0.001 mm, IS-C 0.0001 mm): the files say so, and the error of rounding there is the
// control's input increment.
int length_decimals(bool inch) { return inch ? 8 : 7; }
constexpr int kAngleDecimals = 7;

/// A number as written: fixed decimals, no "-0".
std::string fixed(double v, int decimals, bool plus = false) {
    char buf[64];
    std::snprintf(buf, sizeof buf, plus ? "%+.*f" : "%.*f", decimals, v);
    std::string s = buf;
    // "-0.000" and "+0.000" print as 0.
    if (std::stod(s) == 0.0) {
        std::snprintf(buf, sizeof buf, plus ? "+%.*f" : "%.*f", decimals, 0.0);
        s = buf;
    }
    return s;
}

/// The value a written number stands for.
double as_written(const std::string& s) { return std::stod(s); }

Eigen::Matrix3d rot(const Eigen::Vector3d& axis, double deg) {
    return Eigen::AngleAxisd(deg * kDeg, axis).toRotationMatrix();
}

/// Fanuc G68.2's Euler angles: R = Rz(I) * Rx(J) * Rz(K), J in [0, 180]. At J = 0 or 180 only I -/+ K is
/// fixed: K is taken 0.
Eigen::Vector3d euler_zxz_deg(const Eigen::Matrix3d& R) {
    const double J = std::acos(std::max(-1.0, std::min(1.0, R(2, 2))));
    double I = 0, K = 0;
    if (std::sin(J) > 1e-12) {
        I = std::atan2(R(0, 2), -R(1, 2));
        K = std::atan2(R(2, 0), R(2, 1));
    } else {
        I = std::atan2(R(1, 0), R(0, 0));
    }
    return Eigen::Vector3d(I, J, K) / kDeg;
}

/// The angle of rotation about `u` (unit) nearest R: the twist of R's quaternion about u.
double twist_deg(const Eigen::Matrix3d& R, const Eigen::Vector3d& u) {
    const Eigen::Quaterniond q(R);
    return wrap_deg(2.0 * std::atan2(q.vec().dot(u), q.w()) / kDeg);
}

double corner_error(const Eigen::Isometry3d& written, const Eigen::Isometry3d& T, const Eigen::Vector3d& c) {
    return (written * c - T * c).norm();
}

std::string g_code_for(OffsetDialect d, int n) {
    if (d == OffsetDialect::Heidenhain) return "preset " + std::to_string(n);
    if (d == OffsetDialect::Siemens && n > 4) return "G" + std::to_string(500 + n);
    return "G" + std::to_string(53 + n);
}

/// The comment lines every file carries, without the comment marks.
std::vector<std::string> header(OffsetDialect d, const OffsetSettings& s, const std::string& unit_line,
                                const std::string& cannot, double error, const std::string& what) {
    const std::string u = s.inch ? "in" : "mm";
    std::vector<std::string> lines = {
        "partloc work offset " + std::to_string(s.work_offset) + ", " + g_code_for(d, s.work_offset) + ": " +
            what,
        "the workpiece frame T_machine_workpiece, machine coordinates with every axis at 0",
        "units: " + unit_line + "; " + std::to_string(length_decimals(s.inch)) +
            " decimals, round to the control's input increment",
    };
    lines.push_back("cannot represent: " + (cannot.empty() ? std::string("nothing") : cannot));
    char buf[160];
    std::snprintf(buf, sizeof buf, "error at the part's far corner [%.3f, %.3f, %.3f] %s: %.6f %s",
                  s.far_corner.x(), s.far_corner.y(), s.far_corner.z(), u.c_str(), error, u.c_str());
    lines.push_back(buf);
    for (const auto& n : s.notes) lines.push_back(n);
    return lines;
}

/// Characters a Fanuc comment cannot hold: parentheses close it.
std::string fanuc_comment(std::string s) {
    for (char& c : s)
        if (c == '(' || c == ')') c = ' ';
    return "(" + s + ")";
}

WorkOffsetFile fanuc(const Eigen::Isometry3d& T, const OffsetSettings& s) {
    WorkOffsetFile f;
    const int dl = length_decimals(s.inch);
    const Eigen::Vector3d t = T.translation();
    const Eigen::Vector3d e = euler_zxz_deg(T.linear());
    const std::string X = fixed(t.x(), dl), Y = fixed(t.y(), dl), Z = fixed(t.z(), dl);
    const std::string I = fixed(e.x(), kAngleDecimals), J = fixed(e.y(), kAngleDecimals),
                      K = fixed(e.z(), kAngleDecimals);
    f.T_machine_workpiece_written.translation() =
        Eigen::Vector3d(as_written(X), as_written(Y), as_written(Z));
    f.T_machine_workpiece_written.linear() = rot(Eigen::Vector3d::UnitZ(), as_written(I)) *
                                             rot(Eigen::Vector3d::UnitX(), as_written(J)) *
                                             rot(Eigen::Vector3d::UnitZ(), as_written(K));
    const Eigen::Isometry3d shift_only(Eigen::Translation3d(f.T_machine_workpiece_written.translation()));
    const double without = corner_error(shift_only, T, s.far_corner);
    f.cannot_represent = format(
        "G10 L2 holds no rotation: the rotation is G68.2, the tilted working plane, modal and cancelled by "
        "G69 or reset, so it belongs in the machining programme after %s; G10 L2 alone leaves %.6f %s at "
        "the far corner. Haas: G10 L2 is the same; the tilted plane is Haas's G268, not checked here",
        g_code_for(OffsetDialect::Fanuc, s.work_offset).c_str(), without, s.inch ? "in" : "mm");
    f.error_at_far_corner = corner_error(f.T_machine_workpiece_written, T, s.far_corner);
    std::ostringstream o;
    o << "%\nO0001 " << fanuc_comment("PARTLOC WORK OFFSET") << "\n";
    for (const auto& line : header(OffsetDialect::Fanuc, s, s.inch ? "inch, G20" : "mm, G21",
                                   f.cannot_represent, f.error_at_far_corner, "G10 L2 and G68.2"))
        o << fanuc_comment(line) << "\n";
    o << fanuc_comment("G68.2 X Y Z I J K: Euler angles, about Z by I, the new X by J, the new Z by K")
      << "\n";
    o << (s.inch ? "G20" : "G21") << "\n";
    o << "G90 G10 L2 P" << s.work_offset << " X" << X << " Y" << Y << " Z" << Z << "\n";
    o << g_code_for(OffsetDialect::Fanuc, s.work_offset) << "\n";
    o << "G68.2 X0 Y0 Z0 I" << I << " J" << J << " K" << K << "\n";
    o << fanuc_comment("orient the tool with G53.1 where the machine needs it; G69 cancels") << "\n";
    o << "M30\n%\n";
    f.text = o.str();
    return f;
}

WorkOffsetFile siemens(const Eigen::Isometry3d& T, const OffsetSettings& s) {
    WorkOffsetFile f;
    const int dl = length_decimals(s.inch);
    const Eigen::Vector3d t = T.translation();
    const Eigen::Vector3d e = euler_xyz_deg(T.linear());  // R = Rz(c) Ry(b) Rx(a): RPY, Z, Y', X''
    const std::string X = fixed(t.x(), dl), Y = fixed(t.y(), dl), Z = fixed(t.z(), dl);
    const std::string A = fixed(e.x(), kAngleDecimals), B = fixed(e.y(), kAngleDecimals),
                      C = fixed(e.z(), kAngleDecimals);
    f.T_machine_workpiece_written.translation() =
        Eigen::Vector3d(as_written(X), as_written(Y), as_written(Z));
    f.T_machine_workpiece_written.linear() =
        rotation_from_euler_xyz_deg(Eigen::Vector3d(as_written(A), as_written(B), as_written(C)));
    f.error_at_far_corner = corner_error(f.T_machine_workpiece_written, T, s.far_corner);
    std::ostringstream o;
    o << "; PARTLOC WORK OFFSET\n";
    for (const auto& line : header(OffsetDialect::Siemens, s, s.inch ? "inch, G700" : "mm, G710", "",
                                   f.error_at_far_corner, "settable frame $P_UIFR"))
        o << "; " << line << "\n";
    o << "; CROT angles in RPY order Z, Y', X'' (MD10600 $MN_FRAME_ANGLE_INPUT_MODE = 1, the default)\n";
    o << (s.inch ? "G700" : "G710") << "\n";
    o << "$P_UIFR[" << s.work_offset << "] = CTRANS(X," << X << ",Y," << Y << ",Z," << Z << ") : CROT(X," << A
      << ",Y," << B << ",Z," << C << ")\n";
    o << "; active with " << g_code_for(OffsetDialect::Siemens, s.work_offset)
      << (s.work_offset > 4
              ? " (needs MD28080 $MC_MM_NUM_USER_FRAMES > " + std::to_string(s.work_offset) + ")"
              : "")
      << "\n";
    o << "M30\n";
    f.text = o.str();
    return f;
}

WorkOffsetFile heidenhain(const Eigen::Isometry3d& T, const OffsetSettings& s) {
    WorkOffsetFile f;
    const int dl = length_decimals(s.inch);
    const Eigen::Vector3d t = T.translation();
    const Eigen::Vector3d e = euler_xyz_deg(T.linear());  // R = Rz(SPC) Ry(SPB) Rx(SPA): A, then B, then C
    const std::string X = fixed(t.x(), dl, true), Y = fixed(t.y(), dl, true), Z = fixed(t.z(), dl, true);
    const std::string A = fixed(e.x(), kAngleDecimals, true), B = fixed(e.y(), kAngleDecimals, true),
                      C = fixed(e.z(), kAngleDecimals, true);
    f.T_machine_workpiece_written.translation() =
        Eigen::Vector3d(as_written(X), as_written(Y), as_written(Z));
    f.T_machine_workpiece_written.linear() =
        rotation_from_euler_xyz_deg(Eigen::Vector3d(as_written(A), as_written(B), as_written(C)));
    f.error_at_far_corner = corner_error(f.T_machine_workpiece_written, T, s.far_corner);
    const std::string unit = s.inch ? "INCH" : "MM";
    std::ostringstream o;
    int block = 0;
    o << block++ << " BEGIN PGM heidenhain " << unit << "\n";
    std::vector<std::string> lines = header(OffsetDialect::Heidenhain, s, s.inch ? "inch" : "mm", "",
                                            f.error_at_far_corner, "preset table row");
    lines.push_back("enter this row in the preset table TNC:\\table\\preset.pr; cycle 247 activates it");
    lines.push_back(
        "SPA SPB SPC: 3D basic rotation, spatial angles about the fixed machine axes, A then B then C");
    lines.push_back("on a rotary-table machine the control may refer presets to the table's centre: check");
    for (const auto& line : lines) o << block++ << " ; " << line << "\n";
    o << block++ << " ; PRESET NR=" << s.work_offset << " X=" << X << " Y=" << Y << " Z=" << Z << " SPA=" << A
      << " SPB=" << B << " SPC=" << C << "\n";
    o << block++ << " CYCL DEF 247 DATUM SETTING ~\n    Q339=+" << s.work_offset << " ;DATUM NUMBER\n";
    o << block++ << " END PGM heidenhain " << unit << "\n";
    f.text = o.str();
    return f;
}

WorkOffsetFile linuxcnc(const Eigen::Isometry3d& T, const OffsetSettings& s) {
    WorkOffsetFile f;
    const int dl = length_decimals(s.inch);
    const Eigen::Vector3d t = T.translation();
    // The best frame it holds: the origin as placed, the rotation about Z nearest the placed rotation.
    const double yaw = twist_deg(T.linear(), Eigen::Vector3d::UnitZ());
    const std::string X = fixed(t.x(), dl), Y = fixed(t.y(), dl), Z = fixed(t.z(), dl),
                      R = fixed(yaw, kAngleDecimals);
    f.T_machine_workpiece_written.translation() =
        Eigen::Vector3d(as_written(X), as_written(Y), as_written(Z));
    f.T_machine_workpiece_written.linear() = rot(Eigen::Vector3d::UnitZ(), as_written(R));
    const Eigen::AngleAxisd left(f.T_machine_workpiece_written.linear().transpose() * T.linear());
    f.error_at_far_corner = corner_error(f.T_machine_workpiece_written, T, s.far_corner);
    f.cannot_represent = format(
        "G10 L2 R rotates about Z only: the tilt about X and Y, %.6f degrees, is left out; the origin is as "
        "placed, R the rotation about Z nearest the placed rotation",
        std::abs(left.angle()) / kDeg);
    std::ostringstream o;
    for (const auto& line : header(OffsetDialect::LinuxCnc, s, s.inch ? "inch, G20" : "mm, G21",
                                   f.cannot_represent, f.error_at_far_corner, "G10 L2 with R"))
        o << fanuc_comment(line) << "\n";
    o << (s.inch ? "G20" : "G21") << "\n";
    o << "G10 L2 P" << s.work_offset << " X" << X << " Y" << Y << " Z" << Z << " R" << R << "\n";
    o << "M2\n";
    f.text = o.str();
    return f;
}

/// Rounded to 1e-9 as in result.json; non-finite becomes null.
nlohmann::ordered_json number(double v) {
    if (!std::isfinite(v)) return nullptr;
    const double r = std::round(v * 1e9) / 1e9;
    return r == 0.0 ? 0.0 : r;
}

nlohmann::ordered_json vector3(const Eigen::Vector3d& v) {
    return nlohmann::ordered_json::array({number(v.x()), number(v.y()), number(v.z())});
}

/// The corner of the model's bounding box in the workpiece frame farthest from the workpiece origin.
Eigen::Vector3d far_corner(const ModelSource& m, const Eigen::Isometry3d& T_machine_workpiece) {
    const Eigen::Isometry3d T_workpiece_machine = T_machine_workpiece.inverse();
    Eigen::AlignedBox3d box;
    if (m.mesh)
        for (const auto& v : m.mesh->vertices_) box.extend(T_workpiece_machine * v);
    if (m.points)
        for (const auto& p : m.points->points_) box.extend(T_workpiece_machine * p);
    if (box.isEmpty()) return Eigen::Vector3d::Zero();
    Eigen::Vector3d best = box.min();
    for (int k = 0; k < 8; ++k) {
        const Eigen::Vector3d c = box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(k));
        if (c.norm() > best.norm()) best = c;
    }
    return best;
}

}  // namespace

namespace {

/// Each dialect's name in the job file and its file in DIR/offsets, in one table.
struct DialectNames {
    OffsetDialect dialect;
    const char* name;
    const char* file;
};
constexpr DialectNames kDialects[] = {{OffsetDialect::Fanuc, "fanuc", "fanuc.nc"},
                                      {OffsetDialect::Siemens, "siemens", "siemens.mpf"},
                                      {OffsetDialect::Heidenhain, "heidenhain", "heidenhain.h"},
                                      {OffsetDialect::LinuxCnc, "linuxcnc", "linuxcnc.ngc"}};

const DialectNames* names_of(OffsetDialect d) {
    for (const auto& n : kDialects)
        if (n.dialect == d) return &n;
    return nullptr;
}

}  // namespace

std::string dialect_name(OffsetDialect d) {
    const DialectNames* n = names_of(d);
    return n ? n->name : "";
}

bool parse_dialect(const std::string& name, OffsetDialect& d) {
    for (const auto& n : kDialects)
        if (name == n.name) {
            d = n.dialect;
            return true;
        }
    return false;
}

std::string dialect_file(OffsetDialect d) {
    const DialectNames* n = names_of(d);
    return n ? n->file : "";
}

std::string known_dialects() {
    std::string all;
    for (const auto& n : kDialects) all += (all.empty() ? "" : ", ") + std::string(n.name);
    return all;
}

WorkOffsetFile write_work_offset(OffsetDialect d, const Eigen::Isometry3d& T, const OffsetSettings& s) {
    WorkOffsetFile f;
    switch (d) {
        case OffsetDialect::Fanuc:
            f = fanuc(T, s);
            break;
        case OffsetDialect::Siemens:
            f = siemens(T, s);
            break;
        case OffsetDialect::Heidenhain:
            f = heidenhain(T, s);
            break;
        case OffsetDialect::LinuxCnc:
            f = linuxcnc(T, s);
            break;
    }
    f.dialect = d;
    f.file = dialect_file(d);
    return f;
}

RotaryAxisSquaring square_with_axis(const Axis& axis, const Eigen::Isometry3d& T_located,
                                    const Eigen::Isometry3d& T_nominal) {
    RotaryAxisSquaring r;
    r.axis = axis.name;
    const Eigen::Matrix3d R_dev = T_located.linear() * T_nominal.linear().transpose();
    const Eigen::Vector3d u = axis.direction.normalized();
    r.value_deg = wrap_deg(-twist_deg(R_dev, u));
    const Eigen::AngleAxisd left(rot(u, r.value_deg) * R_dev);
    r.tilt_left_deg = left.axis() * left.angle() / kDeg;
    r.tilt_left_angle_deg = std::abs(left.angle()) / kDeg;
    r.T_machine_workpiece_at_value = axis.motion(r.value_deg) * T_located;
    return r;
}

WorkOffsets work_offsets(const Job& job, const JobResult& result) {
    WorkOffsets w;
    const bool inch = job.units == "in";
    w.units = inch ? "in" : "mm";
    if (job.output.offsets.empty()) return w;
    if (!result.workpiece.valid) {
        w.reason = "the workpiece was not located: no work offsets";
        return w;
    }
    // The placed frame where the final part was placed (SPEC "Machining"), else the located one.
    const Eigen::Isometry3d& T =
        result.machining.available ? result.machining.T_machine_part : result.workpiece.T_machine_workpiece;
    const Eigen::Isometry3d& T_nominal = result.workpiece.T_machine_workpiece_nominal;
    const ModelSource& part =
        job.workpiece.final_part ? *job.workpiece.final_part : job.workpiece.reference_surfaces;
    w.far_corner = far_corner(part, job.workpiece.T_machine_workpiece);
    const double scale = inch ? 1.0 : millimetres_per_unit(job.units);  // job units to file units

    OffsetSettings s;
    s.work_offset = job.output.work_offset;
    s.inch = inch;
    s.far_corner = w.far_corner * scale;
    if (result.machining.available && result.machining.maxmin)
        s.notes.push_back(
            format("the frame is the final part's maxmin placement (result.json placement), "
                   "moved %.6f %s and turned %.6f degrees from the located frame",
                   result.machining.translation * scale, w.units.c_str(), result.machining.rotation_deg));
    for (const auto& name : job.workpiece.moves_with) {
        const Axis* a = job.machine.find(name);
        if (!a || a->type != AxisType::Rotary) continue;
        w.rotary.push_back(square_with_axis(*a, T, T_nominal));
        const RotaryAxisSquaring& r = w.rotary.back();
        s.notes.push_back(
            format("rotary axis %s carries the part: %s = %.6f degrees squares it; the tilt left "
                   "is %.6f degrees, rotation vector [%.6f, %.6f, %.6f] degrees",
                   r.axis.c_str(), r.axis.c_str(), r.value_deg, r.tilt_left_angle_deg, r.tilt_left_deg.x(),
                   r.tilt_left_deg.y(), r.tilt_left_deg.z()));
        s.notes.push_back(
            format("the offset in this file is for %s = 0; at %s = %.6f the origin is at "
                   "[%.6f, %.6f, %.6f] %s",
                   r.axis.c_str(), r.axis.c_str(), r.value_deg,
                   r.T_machine_workpiece_at_value.translation().x() * scale,
                   r.T_machine_workpiece_at_value.translation().y() * scale,
                   r.T_machine_workpiece_at_value.translation().z() * scale, w.units.c_str()));
    }
    Eigen::Isometry3d T_file = T;
    T_file.translation() *= scale;
    for (const auto& name : job.output.offsets) {
        OffsetDialect d;
        if (!parse_dialect(name, d)) continue;  // load_job refuses unknown names
        w.files.push_back(write_work_offset(d, T_file, s));
    }
    w.written = true;
    return w;
}

std::string work_offsets_json(const Job& job, const JobResult& result) {
    using Json = nlohmann::ordered_json;
    const WorkOffsets w = work_offsets(job, result);
    const bool inch = job.units == "in";
    const double to_job = inch ? 1.0 : 1.0 / millimetres_per_unit(job.units);  // file units to job units
    Json j;
    j["written"] = w.written;
    j["message"] = w.reason;
    j["work_offset"] = job.output.work_offset;
    j["file_units"] = w.units;
    j["far_corner"] = w.written ? vector3(w.far_corner) : Json(nullptr);
    Json files = Json::object();
    for (const auto& f : w.files)
        files[dialect_name(f.dialect)] = {{"file", "offsets/" + f.file},
                                          {"cannot_represent", f.cannot_represent},
                                          {"error_at_far_corner", number(f.error_at_far_corner * to_job)}};
    j["files"] = files;
    Json rotary = Json::array();
    for (const auto& r : w.rotary)
        rotary.push_back({{"axis", r.axis},
                          {"value_deg", number(r.value_deg)},
                          {"tilt_left_deg", vector3(r.tilt_left_deg)},
                          {"tilt_left_angle_deg", number(r.tilt_left_angle_deg)},
                          {"origin_at_value", vector3(r.T_machine_workpiece_at_value.translation())}});
    j["rotary_axes"] = rotary;
    return j.dump();
}

std::vector<fs::path> write_work_offsets(const fs::path& dir, const Job& job, const JobResult& result) {
    const WorkOffsets w = work_offsets(job, result);
    std::vector<fs::path> written;
    for (OffsetDialect d :
         {OffsetDialect::Fanuc, OffsetDialect::Siemens, OffsetDialect::Heidenhain, OffsetDialect::LinuxCnc}) {
        const fs::path path = dir / "offsets" / dialect_file(d);
        bool made = false;
        for (const auto& f : w.files)
            if (f.dialect == d) {
                write_text_atomically(path, f.text);
                written.push_back(path);
                made = true;
            }
        if (!made) {
            std::error_code ec;
            fs::remove(path, ec);  // of an earlier run: the folder tells one story
        }
    }
    return written;
}

}  // namespace partloc::io
