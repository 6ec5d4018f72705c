#include "partloc/io/job_io.hpp"

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <initializer_list>
#include <limits>
#include <set>
#include <sstream>

#include "partloc/core/extent.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/formats.hpp"
#include "partloc/io/offsets.hpp"

namespace partloc::io {

namespace fs = std::filesystem;

namespace {

/// The largest coordinate a job may hold, in millimetres: 10 km. Beyond it a number is a corrupt file or a
/// wrong unit, and the arithmetic (squared distances, grids of cells) overflows long before 1e308: a datum
/// origin of 1e308 gave a pose of NaNs, reported as located.
constexpr double kMaxMillimetres = 1e7;

/// A file named in the job, and the factor from its units to the job's.
struct FileRef {
    std::string file;
    double scale = 1.0;
    ModelOptions model;  ///< STEP: its scale to the job's units, the faces by name, the triangulation
};

/// One data file to read once the job is checked: read() fills its place in the Job.
struct FileTask {
    FileRef ref;
    /// Reads the file; what a person should know goes into the last argument (io/cloud_io.hpp).
    std::function<void(const fs::path&, const FileRef&, std::vector<std::string>&)> read;
};

/// Walks the YAML tree; every error names the job file, the field path and the line.
class JobParser {
  public:
    explicit JobParser(std::string job_name) : job_name_(std::move(job_name)) {}

    /// Fills `job` and lists the data files to read into it; the tasks refer to `job`'s members.
    void parse(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks);

  private:
    // parse's sections, in the job file's order.
    void parse_fiducials(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks);
    void parse_workpiece(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks);
    void parse_scans(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks);
    void parse_output(const YAML::Node& root, Job& job);
    void parse_machining(const YAML::Node& workpiece, Job& job);

    [[noreturn]] void fail(const YAML::Node& node, const std::string& path,
                           const std::string& problem) const {
        std::string line;
        if (node.IsDefined() && node.Mark().line >= 0)
            line = " (line " + std::to_string(node.Mark().line + 1) + ")";
        throw InputError(job_name_, path + ": " + problem + line);
    }

    static std::string describe(const YAML::Node& node) {
        if (!node.IsDefined() || node.IsNull()) return "nothing";
        if (node.IsSequence()) return "a list";
        if (node.IsMap()) return "a mapping";
        return "'" + node.Scalar().substr(0, 40) + "'";
    }

    /// Checks that `node` is a mapping with only `known` keys, each once.
    void check_map(const YAML::Node& node, const std::string& path,
                   std::initializer_list<const char*> known) const {
        if (!node.IsMap()) fail(node, path, "expected a mapping, found " + describe(node));
        std::set<std::string> seen;
        for (auto it = node.begin(); it != node.end(); ++it) {
            const std::string key = it->first.IsScalar() ? it->first.Scalar() : "?";
            bool ok = false;
            std::string list;
            for (const char* k : known) {
                ok = ok || key == k;
                list += (list.empty() ? "" : ", ") + std::string(k);
            }
            const std::string at = path.empty() ? key : path + "." + key;
            if (!ok) fail(it->first, at, "unknown field (known here: " + list + ")");
            if (!seen.insert(key).second) fail(it->first, at, "given twice");
        }
    }

    YAML::Node required(const YAML::Node& map, const std::string& path, const char* key) const {
        const YAML::Node n = map[key];
        if (!n.IsDefined() || n.IsNull()) fail(map, join(path, key), "missing");
        return n;
    }

    static std::string join(const std::string& path, const std::string& key) {
        return path.empty() ? key : path + "." + key;
    }

    double number(const YAML::Node& n, const std::string& path) const {
        double v = 0;
        if (!n.IsScalar()) fail(n, path, "expected a number, found " + describe(n));
        const std::string& s = n.Scalar();
        // YAML spells them .nan and .inf; parse_number knows nan and inf.
        if (s == ".nan" || s == ".NaN" || s == ".NAN" || s == ".inf" || s == ".Inf" || s == "-.inf" ||
            s == "+.inf" || !detail::parse_number(s, v))
            fail(n, path, "expected a number, found " + describe(n));
        if (!std::isfinite(v)) fail(n, path, "expected a finite number, found " + describe(n));
        return v;
    }

    double number_at_least(const YAML::Node& n, const std::string& path, double min, bool strict) const {
        const double v = number(n, path);
        if (strict ? !(v > min) : !(v >= min))
            fail(n, path, std::string("must be ") + (strict ? "greater than " : "at least ") + format(min));
        return v;
    }

    static std::string format(double v) {
        std::ostringstream s;
        s << v;
        return s.str();
    }

    Eigen::Vector3d vector3(const YAML::Node& n, const std::string& path) const {
        if (!n.IsSequence() || n.size() != 3)
            fail(n, path,
                 "expected 3 numbers, found " +
                     (n.IsSequence() ? std::to_string(n.size()) + " items" : describe(n)));
        Eigen::Vector3d v;
        for (int i = 0; i < 3; ++i) v[i] = number(n[i], path + "[" + std::to_string(i) + "]");
        return v;
    }

    /// A point or an offset in the machine: 3 numbers, none larger than kMaxMillimetres.
    Eigen::Vector3d position(const YAML::Node& n, const std::string& path) const {
        const Eigen::Vector3d v = vector3(n, path);
        check_length(n, path, v.cwiseAbs().maxCoeff());
        return v;
    }

    void check_length(const YAML::Node& n, const std::string& path, double v) const {
        const double limit = kMaxMillimetres / job_mm_per_unit_;
        if (std::abs(v) > limit)
            fail(n, path,
                 "a coordinate of " + format(v) + " is beyond the " + format(limit) +
                     " (10 km) a machine can hold");
    }

    std::string text(const YAML::Node& n, const std::string& path) const {
        if (!n.IsScalar() || n.Scalar().empty()) fail(n, path, "expected a name, found " + describe(n));
        return n.Scalar();
    }

    double unit_scale(const YAML::Node& n, const std::string& path) const {
        const std::string units = text(n, path);
        try {
            return millimetres_per_unit(units);
        } catch (const std::invalid_argument& e) {
            fail(n, path, e.what());
        }
    }

    FileRef file_ref(const YAML::Node& n, const std::string& path) const {
        FileRef ref;
        if (n.IsScalar()) {
            ref.file = text(n, path);
        } else {
            check_map(n, path, {"file", "units", "faces"});
            ref.file = text(required(n, path, "file"), join(path, "file"));
        }
        const bool step = is_step_file(ref.file);
        // STEP: millimetres from the reader, triangulated to a tenth of the scanner's spacing where the job
        // gives it (the model is sampled at about the spacing), else to 0.02 mm.
        ref.model.step_scale = 1.0 / job_mm_per_unit_;
        if (scanner_spacing_ > 0) ref.model.deflection = 0.1 * scanner_spacing_;
        if (n.IsScalar()) return ref;
        if (n["units"].IsDefined()) {
            if (step)
                fail(n["units"], join(path, "units"),
                     "a STEP file says its own units; leave units out for '" + ref.file + "'");
            ref.scale = unit_scale(n["units"], join(path, "units")) / job_mm_per_unit_;
        }
        if (const YAML::Node f = n["faces"]; f.IsDefined()) {
            const std::string at = join(path, "faces");
            if (!step)
                fail(f, at, "faces can be chosen by name in STEP files only, not in '" + ref.file + "'");
            if (!f.IsSequence() || f.size() == 0)
                fail(f, at, "expected a list of the faces' names in the STEP file, found " + describe(f));
            for (std::size_t i = 0; i < f.size(); ++i)
                ref.model.faces.push_back(text(f[i], at + "[" + std::to_string(i) + "]"));
        }
        return ref;
    }

    /// A pose given as probed points on three planes (core/probe_planes.hpp); recorded for the report.
    Eigen::Isometry3d probed_pose(const YAML::Node& n, const std::string& path) {
        check_map(n, path, {"probe_planes"});
        const YAML::Node lists = n["probe_planes"];
        const std::string at = join(path, "probe_planes");
        if (!lists.IsSequence() || lists.size() != 3)
            fail(lists, at,
                 "expected 3 lists of probed points (the planes x = 0, y = 0, z = 0 of the frame), found " +
                     (lists.IsSequence() ? std::to_string(lists.size()) + " items" : describe(lists)));
        std::array<std::vector<Eigen::Vector3d>, 3> planes;
        for (std::size_t i = 0; i < 3; ++i) {
            const std::string list = at + "[" + std::to_string(i) + "]";
            if (!lists[i].IsSequence())
                fail(lists[i], list, "expected a list of [x, y, z] points, found " + describe(lists[i]));
            for (std::size_t k = 0; k < lists[i].size(); ++k)
                planes[i].push_back(position(lists[i][k], list + "[" + std::to_string(k) + "]"));
        }
        const ProbedFrame frame = frame_from_probe_planes(planes);
        if (!frame.valid) {
            if (frame.plane >= 0)
                fail(lists[frame.plane], at + "[" + std::to_string(frame.plane) + "]", frame.reason);
            fail(lists, at, frame.reason);
        }
        probed_.push_back({path, frame});
        return frame.T;
    }

    Eigen::Isometry3d pose(const YAML::Node& n, const std::string& path) {
        if (n.IsMap() && n["probe_planes"].IsDefined()) return probed_pose(n, path);
        if (n.IsMap() && n["matrix"].IsDefined()) {
            check_map(n, path, {"matrix"});
            const YAML::Node m = n["matrix"];
            const std::string at = join(path, "matrix");
            if (!m.IsSequence() || m.size() != 4)
                fail(m, at,
                     "expected 4 rows of 4 numbers, found " +
                         (m.IsSequence() ? std::to_string(m.size()) + " rows" : describe(m)));
            Eigen::Matrix4d M;
            for (int r = 0; r < 4; ++r) {
                const std::string row = at + "[" + std::to_string(r) + "]";
                if (!m[r].IsSequence() || m[r].size() != 4)
                    fail(m[r], row,
                         "expected 4 numbers, found " +
                             (m[r].IsSequence() ? std::to_string(m[r].size()) + " items" : describe(m[r])));
                for (int c = 0; c < 4; ++c) M(r, c) = number(m[r][c], row + "[" + std::to_string(c) + "]");
                if (r < 3) check_length(m[r][3], row + "[3]", M(r, 3));
            }
            try {
                return checked_isometry(M, at);
            } catch (const std::invalid_argument& e) {
                const std::string what = e.what();
                fail(m, at, what.substr(std::min(what.size(), at.size() + 2)));
            }
        }
        check_map(n, path, {"origin", "euler_xyz_deg", "matrix", "probe_planes"});
        const Eigen::Vector3d origin = position(required(n, path, "origin"), join(path, "origin"));
        const Eigen::Vector3d euler = n["euler_xyz_deg"].IsDefined()
                                          ? vector3(n["euler_xyz_deg"], join(path, "euler_xyz_deg"))
                                          : Eigen::Vector3d::Zero();
        if (euler.cwiseAbs().maxCoeff() > 1e6)
            fail(n["euler_xyz_deg"], join(path, "euler_xyz_deg"), "an angle beyond a million degrees");
        return pose_from_origin_euler(origin, euler);
    }

    void check_axis(const YAML::Node& n, const std::string& path, const std::string& axis) const {
        if (machine_.find(axis)) return;
        fail(n, path,
             "machine.axes has no axis '" + axis + "'" +
                 (machine_.axes.empty() ? " (the job has no machine block)" : ""));
    }

    std::vector<std::string> axis_chain(const YAML::Node& n, const std::string& path) const {
        std::vector<std::string> chain;
        if (!n.IsDefined() || n.IsNull()) return chain;
        if (!n.IsSequence()) fail(n, path, "expected a list of axis names, found " + describe(n));
        for (std::size_t i = 0; i < n.size(); ++i) {
            const std::string at = path + "[" + std::to_string(i) + "]";
            const std::string axis = text(n[i], at);
            check_axis(n[i], at, axis);
            for (const auto& a : chain)
                if (a == axis) fail(n[i], at, "axis '" + axis + "' named twice");
            chain.push_back(axis);
        }
        return chain;
    }

    AxisValues axis_values(const YAML::Node& n, const std::string& path) const {
        AxisValues q;
        if (!n.IsDefined() || n.IsNull()) return q;
        if (!n.IsMap()) fail(n, path, "expected a mapping of axis name to value, found " + describe(n));
        for (auto it = n.begin(); it != n.end(); ++it) {
            const std::string axis = text(it->first, path);
            const std::string at = join(path, axis);
            check_axis(it->first, at, axis);
            if (q.count(axis)) fail(it->first, at, "given twice");
            q[axis] = number(it->second, at);
            check_length(it->second, at, q[axis]);
        }
        return q;
    }

    Machine machine(const YAML::Node& n) const {
        Machine m;
        if (!n.IsDefined() || n.IsNull()) return m;
        check_map(n, "machine", {"axes"});
        const YAML::Node axes = n["axes"];
        if (!axes.IsDefined() || axes.IsNull()) return m;
        if (!axes.IsSequence())
            fail(axes, "machine.axes", "expected a list of axes, found " + describe(axes));
        for (std::size_t i = 0; i < axes.size(); ++i) {
            const YAML::Node a = axes[i];
            const std::string at = "machine.axes[" + std::to_string(i) + "]";
            check_map(a, at, {"name", "type", "direction", "point"});
            Axis axis;
            axis.name = text(required(a, at, "name"), at + ".name");
            if (m.find(axis.name)) fail(a["name"], at + ".name", "axis '" + axis.name + "' defined twice");
            const std::string type = text(required(a, at, "type"), at + ".type");
            if (type == "linear")
                axis.type = AxisType::Linear;
            else if (type == "rotary")
                axis.type = AxisType::Rotary;
            else
                fail(a["type"], at + ".type", "expected linear or rotary, found '" + type + "'");
            const Eigen::Vector3d d = vector3(required(a, at, "direction"), at + ".direction");
            if (d.isZero(0.0)) fail(a["direction"], at + ".direction", "must not be zero");
            // Its length does not matter: [1e200, 0, 0] and [1e-200, 0, 0] are [1, 0, 0]. Their norms
            // overflow or underflow, so such a vector is first divided by its largest coordinate; one of
            // ordinary length is normalised as it was, bit for bit.
            const double length = d.norm();
            axis.direction = length > 1e-100 && length < 1e100 ? d.normalized()
                                                               : (d / d.cwiseAbs().maxCoeff()).normalized();
            if (axis.type == AxisType::Rotary)
                axis.point = position(required(a, at, "point"), at + ".point");
            else if (a["point"].IsDefined())
                axis.point = position(a["point"], at + ".point");
            m.axes.push_back(axis);
        }
        return m;
    }

    std::string job_name_;
    double job_mm_per_unit_ = 1.0;
    double scanner_spacing_ = 0.0;  ///< scanner.point_spacing where the job gives it (job units)
    Machine machine_;
    std::vector<ProbedPose> probed_;
};

void JobParser::parse(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks) {
    if (!root.IsDefined() || root.IsNull()) throw InputError(job_name_, "the job file is empty");
    if (!root.IsMap())
        throw InputError(job_name_, "expected a mapping with units, fiducials, workpiece and scans, found " +
                                        describe(root));
    check_map(
        root, "",
        {"units", "scanner", "machine", "fiducials", "workpiece", "scans", "output", "name", "description"});

    if (root["units"].IsDefined()) {
        job_mm_per_unit_ = unit_scale(root["units"], "units");
        job.units = root["units"].Scalar();
    }

    if (const YAML::Node s = root["scanner"]; s.IsDefined() && !s.IsNull()) {
        check_map(s, "scanner", {"point_spacing", "noise"});
        if (s["point_spacing"].IsDefined()) {
            job.scanner.point_spacing = number_at_least(s["point_spacing"], "scanner.point_spacing", 0, true);
            check_length(s["point_spacing"], "scanner.point_spacing", *job.scanner.point_spacing);
            scanner_spacing_ = *job.scanner.point_spacing;
        }
        if (s["noise"].IsDefined()) {
            job.scanner.noise = number_at_least(s["noise"], "scanner.noise", 0, false);
            check_length(s["noise"], "scanner.noise", *job.scanner.noise);
        }
    }

    machine_ = machine(root["machine"]);
    job.machine = machine_;

    parse_fiducials(root, job, tasks);
    parse_workpiece(root, job, tasks);
    parse_scans(root, job, tasks);
    parse_output(root, job);
}

void JobParser::parse_fiducials(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks) {
    const YAML::Node fiducials = required(root, "", "fiducials");
    if (!fiducials.IsSequence() || fiducials.size() == 0)
        fail(fiducials, "fiducials",
             "expected a list of one or more fiducials, found " + describe(fiducials));
    job.fiducials.resize(fiducials.size());
    for (std::size_t i = 0; i < fiducials.size(); ++i) {
        const YAML::Node f = fiducials[i];
        const std::string at = "fiducials[" + std::to_string(i) + "]";
        check_map(f, at, {"name", "model", "pose", "probed_at", "moves_with", "pose_sigma"});
        Fiducial& fid = job.fiducials[i];
        fid.name = text(required(f, at, "name"), at + ".name");
        for (std::size_t j = 0; j < i; ++j)
            if (job.fiducials[j].name == fid.name)
                fail(f["name"], at + ".name",
                     "fiducial name '" + fid.name + "' is already used by fiducials[" + std::to_string(j) +
                         "]");
        const FileRef model = file_ref(required(f, at, "model"), at + ".model");
        fid.T_machine_fiducial = pose(required(f, at, "pose"), at + ".pose");
        fid.probed_at = axis_values(f["probed_at"], at + ".probed_at");
        fid.moves_with = axis_chain(f["moves_with"], at + ".moves_with");
        // An explicit default, in the job's units, so that what reads the job reads a real number.
        fid.pose_sigma = f["pose_sigma"].IsDefined()
                             ? number_at_least(f["pose_sigma"], at + ".pose_sigma", 0, false)
                             : 0.005 / job_mm_per_unit_;
        tasks.push_back(
            {model, [&fid](const fs::path& p, const FileRef& r, std::vector<std::string>& warnings) {
                 fid.model = read_model(p, r.file, r.scale, &warnings, r.model);
             }});
    }
}

void JobParser::parse_workpiece(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks) {
    const YAML::Node w = required(root, "", "workpiece");
    check_map(w, "workpiece",
              {"reference_surfaces", "datum", "final_part", "moves_with", "region", "datums", "fit",
               "allowance", "placement"});
    if (const YAML::Node d = w["datums"]; d.IsDefined() && !d.IsNull()) {
        if (!d.IsSequence() || d.size() != 3)
            fail(d, "workpiece.datums",
                 "expected 3 datums (primary, secondary, tertiary), found " +
                     (d.IsSequence() ? std::to_string(d.size()) + " items" : describe(d)));
        job.workpiece.datums.resize(d.size());
        for (std::size_t i = 0; i < d.size(); ++i) {
            const std::string at = "workpiece.datums[" + std::to_string(i) + "]";
            check_map(d[i], at, {"name", "surfaces"});
            Datum& datum = job.workpiece.datums[i];
            datum.name = text(required(d[i], at, "name"), at + ".name");
            for (std::size_t j = 0; j < i; ++j)
                if (job.workpiece.datums[j].name == datum.name)
                    fail(d[i]["name"], at + ".name",
                         "datum name '" + datum.name + "' is already used by workpiece.datums[" +
                             std::to_string(j) + "]");
            const FileRef surfaces = file_ref(required(d[i], at, "surfaces"), at + ".surfaces");
            tasks.push_back(
                {surfaces, [&datum](const fs::path& p, const FileRef& r, std::vector<std::string>& warnings) {
                     datum.surfaces = read_model(p, r.file, r.scale, &warnings, r.model);
                 }});
        }
    }
    const bool has_datums = !job.workpiece.datums.empty();
    job.workpiece.fit = has_datums ? WorkpieceFitMode::Datums : WorkpieceFitMode::Simultaneous;
    if (const YAML::Node f = w["fit"]; f.IsDefined()) {
        const std::string mode = text(f, "workpiece.fit");
        if (mode == "simultaneous")
            job.workpiece.fit = WorkpieceFitMode::Simultaneous;
        else if (mode == "datums")
            job.workpiece.fit = WorkpieceFitMode::Datums;
        else
            fail(f, "workpiece.fit", "expected simultaneous or datums, found '" + mode + "'");
        if (mode == "datums" && !has_datums) fail(f, "workpiece.fit", "datums needs workpiece.datums");
    }
    // With datums, the reference surfaces may be left out: they are then the datums' union (load_job).
    if (!has_datums || (w["reference_surfaces"].IsDefined() && !w["reference_surfaces"].IsNull())) {
        const FileRef reference =
            file_ref(required(w, "workpiece", "reference_surfaces"), "workpiece.reference_surfaces");
        tasks.push_back(
            {reference, [&job](const fs::path& p, const FileRef& r, std::vector<std::string>& warnings) {
                 job.workpiece.reference_surfaces = read_model(p, r.file, r.scale, &warnings, r.model);
             }});
    }
    if (w["datum"].IsDefined()) job.workpiece.T_machine_workpiece = pose(w["datum"], "workpiece.datum");
    if (w["final_part"].IsDefined() && !w["final_part"].IsNull()) {
        const FileRef part = file_ref(w["final_part"], "workpiece.final_part");
        tasks.push_back(
            {part, [&job](const fs::path& p, const FileRef& r, std::vector<std::string>& warnings) {
                 job.workpiece.final_part = read_model(p, r.file, r.scale, &warnings, r.model);
             }});
    }
    job.workpiece.moves_with = axis_chain(w["moves_with"], "workpiece.moves_with");
    if (const YAML::Node r = w["region"]; r.IsDefined() && !r.IsNull()) {
        check_map(r, "workpiece.region", {"min", "max"});
        const Eigen::Vector3d lo = position(required(r, "workpiece.region", "min"), "workpiece.region.min");
        const Eigen::Vector3d hi = position(required(r, "workpiece.region", "max"), "workpiece.region.max");
        if ((hi - lo).minCoeff() <= 0)
            fail(r, "workpiece.region", "max must be greater than min on every axis");
        job.workpiece.region = Eigen::AlignedBox3d(lo, hi);
    }
    parse_machining(w, job);
}

void JobParser::parse_machining(const YAML::Node& w, Job& job) {
    const bool has_part = w["final_part"].IsDefined() && !w["final_part"].IsNull();
    if (const YAML::Node a = w["allowance"]; a.IsDefined() && !a.IsNull()) {
        check_map(a, "workpiece.allowance", {"min"});
        if (!has_part) fail(a, "workpiece.allowance", "needs workpiece.final_part (the part to be cut)");
        job.workpiece.allowance_min =
            number_at_least(required(a, "workpiece.allowance", "min"), "workpiece.allowance.min", 0, false);
    }
    const YAML::Node p = w["placement"];
    if (!p.IsDefined() || p.IsNull()) return;
    const std::string at = "workpiece.placement";
    check_map(p, at, {"mode", "free", "limits"});
    PlacementSpec& spec = job.workpiece.placement;
    if (const YAML::Node m = p["mode"]; m.IsDefined()) {
        const std::string mode = text(m, at + ".mode");
        if (mode != "located" && mode != "maxmin")
            fail(m, at + ".mode", "expected located or maxmin, found '" + mode + "'");
        spec.maxmin = mode == "maxmin";
    }
    if (spec.maxmin && !has_part) fail(p, at, "maxmin needs workpiece.final_part (the part to be placed)");
    if (const YAML::Node f = p["free"]; f.IsDefined()) {
        if (!f.IsSequence())
            fail(f, at + ".free",
                 "expected a list of degrees of freedom (x, y, z, a, b, c), found " + describe(f));
        spec.free.fill(false);
        const std::string names = "xyzabc";
        for (std::size_t i = 0; i < f.size(); ++i) {
            const std::string path = at + ".free[" + std::to_string(i) + "]";
            const std::string dof = text(f[i], path);
            const std::size_t k =
                dof.size() == 1 ? names.find(static_cast<char>(std::tolower(dof[0]))) : std::string::npos;
            if (k == std::string::npos)
                fail(f[i], path, "expected one of x, y, z, a, b, c, found '" + dof + "'");
            if (spec.free[k]) fail(f[i], path, "'" + dof + "' is given twice");
            spec.free[k] = true;
        }
    }
    if (const YAML::Node l = p["limits"]; l.IsDefined() && !l.IsNull()) {
        check_map(l, at + ".limits", {"translation", "rotation_deg"});
        if (l["translation"].IsDefined())
            spec.max_translation = number_at_least(l["translation"], at + ".limits.translation", 0, false);
        if (l["rotation_deg"].IsDefined())
            spec.max_rotation_deg = number_at_least(l["rotation_deg"], at + ".limits.rotation_deg", 0, false);
    }
}

void JobParser::parse_scans(const YAML::Node& root, Job& job, std::vector<FileTask>& tasks) {
    const YAML::Node scans = required(root, "", "scans");
    if (!scans.IsSequence() || scans.size() == 0)
        fail(scans, "scans", "expected a list of one or more scans, found " + describe(scans));
    job.scans.resize(scans.size());
    for (std::size_t i = 0; i < scans.size(); ++i) {
        const YAML::Node s = scans[i];
        const std::string at = "scans[" + std::to_string(i) + "]";
        Scan& scan = job.scans[i];
        FileRef ref;
        if (s.IsScalar()) {
            ref = file_ref(s, at);
        } else {
            // {file, units, axes}: the file entry's units sit beside its axes.
            check_map(s, at, {"file", "units", "axes"});
            ref.file = text(required(s, at, "file"), at + ".file");
            if (s["units"].IsDefined()) ref.scale = unit_scale(s["units"], at + ".units") / job_mm_per_unit_;
            scan.axes = axis_values(s["axes"], at + ".axes");
        }
        scan.file = ref.file;
        tasks.push_back(
            {ref, [&scan](const fs::path& p, const FileRef& r, std::vector<std::string>& warnings) {
                 auto cloud = read_point_cloud(p, r.file, r.scale, &warnings);
                 // One point at 1e9 in a scan of 200 mm is a glitch, not part of the scene:
                 // dropped and named, so that it neither spoils the scan nor passes unseen.
                 if (const std::size_t far = remove_far_points(cloud->points_, cloud->normals_))
                     warnings.push_back(r.file + ": " + std::to_string(far) +
                                        (far == 1 ? " point lies" : " points lie") +
                                        " more than 100 times the scan's size from the rest "
                                        "and " +
                                        (far == 1 ? "was" : "were") + " left out");
                 scan.points = std::move(cloud);
             }});
    }
    job.probed_poses = probed_;
}

void JobParser::parse_output(const YAML::Node& root, Job& job) {
    // output: the work-offset files (SPEC "Machining"); 1..6 is what all four dialects take (G54..G59).
    if (const YAML::Node o = root["output"]; o.IsDefined() && !o.IsNull()) {
        check_map(o, "output", {"offsets", "work_offset"});
        if (const YAML::Node d = o["offsets"]; d.IsDefined() && !d.IsNull()) {
            const std::string known = known_dialects();
            if (!d.IsSequence())
                fail(d, "output.offsets",
                     "expected a list of dialects (" + known + "), found " + describe(d));
            for (std::size_t i = 0; i < d.size(); ++i) {
                const std::string at = "output.offsets[" + std::to_string(i) + "]";
                const std::string name = text(d[i], at);
                OffsetDialect dialect;
                if (!parse_dialect(name, dialect))
                    fail(d[i], at, "unknown dialect '" + name + "' (known: " + known + ")");
                for (const auto& n : job.output.offsets)
                    if (n == name) fail(d[i], at, "dialect '" + name + "' named twice");
                job.output.offsets.push_back(name);
            }
        }
        if (const YAML::Node n = o["work_offset"]; n.IsDefined()) {
            const double v = number(n, "output.work_offset");
            if (v != std::floor(v) || v < 1 || v > kMaxWorkOffset)
                fail(n, "output.work_offset",
                     "must be a whole number from 1 (G54, the first preset) to " +
                         std::to_string(kMaxWorkOffset) + " (G59), found " + describe(n));
            job.output.work_offset = static_cast<int>(v);
        }
    }
}

std::string shortest(double v) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%.3g", v);
    return buffer;
}

const std::vector<Eigen::Vector3d>& vertices_of(const ModelSource& m) {
    static const std::vector<Eigen::Vector3d> none;
    return m.mesh ? m.mesh->vertices_ : m.points ? m.points->points_ : none;
}

}  // namespace

/// The checks of extent and rank that the algorithms need of the data (core/extent.hpp), made where the
/// data enters so that the message names the file: Open3D's hull and Delaunay (Qhull) throw on planar or
/// collinear points, its KD-tree and voxel grid on points of no extent or of an extent of more than 2^31
/// cells, the pose search's tables grow with the model's size over the point spacing.
void check_job_geometry(const Job& job, const std::string& job_name) {
    const double max_length = kMaxMillimetres / millimetres_per_unit(job.units);
    const std::string unit = " " + job.units;
    const auto check = [&](const std::string& file, const std::vector<Eigen::Vector3d>& points,
                           std::size_t min_points, const std::string& what, const char* needs, int min_rank) {
        const Extent e = extent_of(points);
        if (e.points < min_points)
            throw InputError(file, "has only " + std::to_string(e.points) +
                                       (e.points == 1 ? " point" : " points") + "; " + what +
                                       " needs at least " + std::to_string(min_points));
        if (!(e.max_abs <= max_length))
            throw InputError(file, "coordinates reach " + shortest(e.max_abs) + unit + ", beyond the " +
                                       shortest(max_length) + unit +
                                       " (10 km) a machine can hold: a wrong unit or a corrupt file?");
        const std::string problem = rank_problem(e, min_rank);
        if (!problem.empty()) throw InputError(file, problem + "; " + what + " needs " + needs);
        return e;
    };
    double largest_scan = 0, densest_spacing = std::numeric_limits<double>::infinity();
    for (const Scan& s : job.scans) {
        const Extent e =
            check(s.file, s.points->points_, 10, "a scan", "points spread in three dimensions", 3);
        largest_scan = std::max(largest_scan, e.diagonal);
        densest_spacing = std::min(densest_spacing, e.diagonal / std::sqrt(static_cast<double>(e.points)));
    }
    for (const Fiducial& f : job.fiducials) {
        const Extent e =
            check(f.model.file, vertices_of(f.model), 4, "a fiducial", "a three-dimensional shape", 3);
        if (e.diagonal > 1000 * largest_scan)
            throw InputError(f.model.file, "the model is " + shortest(e.diagonal / largest_scan) +
                                               " times larger than the largest scan (" +
                                               shortest(e.diagonal) + " against " + shortest(largest_scan) +
                                               unit + "): a wrong unit?");
    }
    const Workpiece& w = job.workpiece;
    if (w.reference_surfaces.mesh || w.reference_surfaces.points)
        check(w.reference_surfaces.file, vertices_of(w.reference_surfaces), 3, "a set of reference surfaces",
              "at least a surface",
              2);  // one plane is enough for a plate's top (3 of the 6 degrees of freedom)
    if (w.final_part)
        check(w.final_part->file, vertices_of(*w.final_part), 3, "the final part", "a surface", 2);
    // A spacing far below what the scans can have (their diagonal over the root of their count is about
    // their spacing) sizes grids and Open3D's voxel downsampling by it: 1e-9 mm asks 2^31 cells and more.
    if (job.scanner.point_spacing && *job.scanner.point_spacing < densest_spacing / 100)
        throw InputError(job_name, "scanner.point_spacing: " + shortest(*job.scanner.point_spacing) + unit +
                                       " is less than a hundredth of what the scans can have (about " +
                                       shortest(densest_spacing) + unit + "): a wrong unit?");
}

namespace {

std::string read_job_text(const fs::path& job_file, const std::string& name) {
    try {
        return detail::read_file_bytes(job_file, name);
    } catch (const InputError& e) {
        if (e.problem() == "file is empty") throw InputError(name, "the job file is empty");
        throw;
    }
}

}  // namespace

Job load_job(const fs::path& job_file, const LoadOptions& options) {
    const std::string name = job_file.string();
    const std::string text = read_job_text(job_file, name);
    YAML::Node root;
    try {
        root = YAML::Load(text);
    } catch (const YAML::Exception& e) {
        throw InputError(name, "not valid YAML or JSON: " + e.msg + " (line " +
                                   std::to_string(e.mark.line + 1) + ", column " +
                                   std::to_string(e.mark.column + 1) + ")");
    }

    Job job;
    std::vector<FileTask> tasks;
    JobParser parser(name);
    try {
        parser.parse(root, job, tasks);
    } catch (const YAML::Exception& e) {
        // yaml-cpp throws on what the checks above did not foresee; still one line naming the job file.
        throw InputError(name, "malformed job: " + e.msg + " (line " + std::to_string(e.mark.line + 1) + ")");
    }

    // Each task fills its own place in `job`, so the result does not depend on the order they finish in; of
    // several bad files the first in the job is reported.
    const fs::path base = job_file.parent_path();
    std::vector<std::exception_ptr> errors(tasks.size());
    std::vector<std::vector<std::string>> warnings(tasks.size());
    const auto run = [&](std::size_t i) {
        try {
            fs::path path = tasks[i].ref.file;
            if (path.is_relative()) path = base / path;
            tasks[i].read(path, tasks[i].ref, warnings[i]);
        } catch (...) {
            errors[i] = std::current_exception();
        }
    };
    // TBB prints a warning when an arena asks for more threads than the process allows; library code must
    // not print, so ask for no more.
    const int allowed =
        static_cast<int>(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
    tbb::task_arena arena(options.threads > 0 ? std::min(options.threads, allowed)
                                              : tbb::task_arena::automatic);
    arena.execute([&] { tbb::parallel_for(std::size_t(0), tasks.size(), run); });
    for (const auto& e : errors)
        if (e) std::rethrow_exception(e);
    for (const auto& w : warnings) job.warnings.insert(job.warnings.end(), w.begin(), w.end());
    Workpiece& w = job.workpiece;
    if (!w.reference_surfaces.mesh && !w.reference_surfaces.points && !w.datums.empty())
        w.reference_surfaces = union_of_datums(w.datums);
    return job;
}

}  // namespace partloc::io
