#include "partloc/io/job_writer.hpp"

#include <open3d/io/TriangleMeshIO.h>
#include <yaml-cpp/yaml.h>

#include <cctype>
#include <cmath>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "partloc/core/geometry.hpp"
#include "partloc/io/atomic_file.hpp"
#include "partloc/io/cloud_io.hpp"

namespace partloc::io {

namespace fs = std::filesystem;

namespace {

/// Tidies a number for the job file: round-off dust (|x| < 1e-12) and -0 become 0.
double tidy(double x) { return std::abs(x) < 1e-12 ? 0.0 : x; }

void emit_vector(YAML::Emitter& out, const Eigen::Vector3d& v) {
    out << YAML::Flow << YAML::BeginSeq << tidy(v.x()) << tidy(v.y()) << tidy(v.z()) << YAML::EndSeq;
}

void emit_pose(YAML::Emitter& out, const Eigen::Isometry3d& T) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "origin" << YAML::Value;
    emit_vector(out, T.translation());
    out << YAML::Key << "euler_xyz_deg" << YAML::Value;
    emit_vector(out, euler_xyz_deg(T.linear()));
    out << YAML::EndMap;
}

void emit_names(YAML::Emitter& out, const std::vector<std::string>& names) {
    out << YAML::Flow << YAML::BeginSeq;
    for (const auto& n : names) out << n;
    out << YAML::EndSeq;
}

void emit_axes(YAML::Emitter& out, const AxisValues& q) {
    out << YAML::Flow << YAML::BeginMap;
    for (const auto& [name, value] : q) out << YAML::Key << name << YAML::Value << tidy(value);
    out << YAML::EndMap;
}

/// The target of a relative `file` under dir; refuses absolute paths and paths that climb out of dir.
fs::path target(const fs::path& dir, const std::string& file, const std::string& what) {
    if (file.empty()) throw std::invalid_argument(what + ": has no file name");
    const fs::path rel(file);
    if (rel.is_absolute())
        throw std::invalid_argument(what + ": file '" + file + "' must be relative to the job");
    for (const auto& part : rel)
        if (part == "..")
            throw std::invalid_argument(what + ": file '" + file + "' must stay inside the job folder");
    return dir / rel;
}

bool has_extension(const fs::path& path, const char* ext) {
    std::string e = path.extension().string();
    for (auto& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return e == ext;
}

/// STL through the I/O layer's writer; PLY and OBJ meshes through Open3D's, chosen by the extension.
void write_mesh_file(const fs::path& path, const open3d::geometry::TriangleMesh& mesh) {
    if (has_extension(path, ".stl")) return write_mesh(path, mesh, "partloc model");
    open3d::geometry::TriangleMesh copy = mesh;
    if (!copy.HasTriangleNormals()) copy.ComputeTriangleNormals(true);
    write_atomically(path, [&](const fs::path& tmp) {
        return open3d::io::WriteTriangleMesh(tmp.string(), copy, /*write_ascii=*/false, /*compressed=*/false,
                                             /*write_vertex_normals=*/false, /*write_vertex_colors=*/false,
                                             /*write_triangle_uvs=*/false, /*print_progress=*/false);
    });
}

void write_model(const fs::path& dir, const ModelSource& m, const std::string& what) {
    const fs::path path = target(dir, m.file, what);
    if (m.mesh)
        write_mesh_file(path, *m.mesh);
    else if (m.points)
        write_point_cloud(path, *m.points);
    else
        throw std::invalid_argument(what + ": '" + m.file + "' has neither a mesh nor points to write");
}

nlohmann::json matrix_json(const Eigen::Isometry3d& T) {
    nlohmann::json rows = nlohmann::json::array();
    for (int r = 0; r < 4; ++r)
        rows.push_back({T.matrix()(r, 0), T.matrix()(r, 1), T.matrix()(r, 2), T.matrix()(r, 3)});
    return rows;
}

nlohmann::json vector_json(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

nlohmann::json pose_json(const Eigen::Isometry3d& T) {
    return {{"matrix", matrix_json(T)},
            {"origin", vector_json(T.translation())},
            {"euler_xyz_deg", vector_json(euler_xyz_deg(T.linear()))}};
}

}  // namespace

void write_job(const fs::path& dir, const Job& job) {
    for (const auto& f : job.fiducials) write_model(dir, f.model, "fiducial " + f.name);
    write_model(dir, job.workpiece.reference_surfaces, "workpiece reference_surfaces");
    if (job.workpiece.final_part) write_model(dir, *job.workpiece.final_part, "workpiece final_part");
    for (const auto& d : job.workpiece.datums) write_model(dir, d.surfaces, "workpiece datum " + d.name);
    for (const auto& s : job.scans) {
        if (!s.points) throw std::invalid_argument("scan '" + s.file + "': has no points to write");
        write_point_cloud(target(dir, s.file, "scan"), *s.points, "scan frame, units " + job.units);
    }

    YAML::Emitter out;
    out.SetDoublePrecision(12);  // sub-nanometre in mm, 1e-10 degree: the values as computed
    out << YAML::BeginMap;
    out << YAML::Key << "units" << YAML::Value << job.units;
    if (job.scanner.point_spacing || job.scanner.noise) {
        out << YAML::Key << "scanner" << YAML::Value << YAML::BeginMap;
        if (job.scanner.point_spacing)
            out << YAML::Key << "point_spacing" << YAML::Value << *job.scanner.point_spacing;
        if (job.scanner.noise) out << YAML::Key << "noise" << YAML::Value << *job.scanner.noise;
        out << YAML::EndMap;
    }
    if (!job.machine.axes.empty()) {
        out << YAML::Key << "machine" << YAML::Value << YAML::BeginMap << YAML::Key << "axes" << YAML::Value
            << YAML::BeginSeq;
        for (const auto& a : job.machine.axes) {
            out << YAML::Flow << YAML::BeginMap;
            out << YAML::Key << "name" << YAML::Value << a.name;
            out << YAML::Key << "type" << YAML::Value << (a.type == AxisType::Rotary ? "rotary" : "linear");
            out << YAML::Key << "direction" << YAML::Value;
            emit_vector(out, a.direction);
            if (a.type == AxisType::Rotary) {
                out << YAML::Key << "point" << YAML::Value;
                emit_vector(out, a.point);
            }
            out << YAML::EndMap;
        }
        out << YAML::EndSeq << YAML::EndMap;
    }
    out << YAML::Key << "fiducials" << YAML::Value << YAML::BeginSeq;
    for (const auto& f : job.fiducials) {
        out << YAML::BeginMap;
        out << YAML::Key << "name" << YAML::Value << f.name;
        out << YAML::Key << "model" << YAML::Value << f.model.file;
        out << YAML::Key << "pose" << YAML::Value;
        emit_pose(out, f.T_machine_fiducial);
        if (!f.probed_at.empty()) {
            out << YAML::Key << "probed_at" << YAML::Value;
            emit_axes(out, f.probed_at);
        }
        out << YAML::Key << "moves_with" << YAML::Value;
        emit_names(out, f.moves_with);
        out << YAML::EndMap;
    }
    out << YAML::EndSeq;

    const Workpiece& w = job.workpiece;
    out << YAML::Key << "workpiece" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "reference_surfaces" << YAML::Value << w.reference_surfaces.file;
    out << YAML::Key << "datum" << YAML::Value;
    emit_pose(out, w.T_machine_workpiece);
    if (w.final_part) out << YAML::Key << "final_part" << YAML::Value << w.final_part->file;
    out << YAML::Key << "moves_with" << YAML::Value;
    emit_names(out, w.moves_with);
    if (w.region) {
        out << YAML::Key << "region" << YAML::Value << YAML::Flow << YAML::BeginMap;
        out << YAML::Key << "min" << YAML::Value;
        emit_vector(out, w.region->min());
        out << YAML::Key << "max" << YAML::Value;
        emit_vector(out, w.region->max());
        out << YAML::EndMap;
    }
    if (!w.datums.empty()) {
        out << YAML::Key << "datums" << YAML::Value << YAML::BeginSeq;
        for (const auto& d : w.datums)
            out << YAML::Flow << YAML::BeginMap << YAML::Key << "name" << YAML::Value << d.name << YAML::Key
                << "surfaces" << YAML::Value << d.surfaces.file << YAML::EndMap;
        out << YAML::EndSeq;
        out << YAML::Key << "fit" << YAML::Value
            << (w.fit == WorkpieceFitMode::Datums ? "datums" : "simultaneous");
    }
    out << YAML::EndMap;

    out << YAML::Key << "scans" << YAML::Value << YAML::BeginSeq;
    for (const auto& s : job.scans) {
        out << YAML::Flow << YAML::BeginMap;
        out << YAML::Key << "file" << YAML::Value << s.file;
        out << YAML::Key << "axes" << YAML::Value;
        emit_axes(out, s.axes);
        out << YAML::EndMap;
    }
    out << YAML::EndSeq << YAML::EndMap;
    if (!out.good()) throw std::runtime_error((dir / "job.yaml").string() + ": " + out.GetLastError());
    write_text_atomically(dir / "job.yaml", std::string(out.c_str()) + "\n");
}

void write_truth(const fs::path& path, const sim::Truth& truth) {
    nlohmann::json j;
    j["scenario"] = truth.scenario;
    j["seed"] = truth.seed;
    j["units"] = truth.units;
    const Eigen::Isometry3d& T = truth.T_machine_workpiece;
    const Eigen::Isometry3d& N = truth.T_machine_workpiece_nominal;
    j["workpiece"] = {
        {"T_machine_workpiece", matrix_json(T)},
        {"origin", vector_json(T.translation())},
        {"euler_xyz_deg", vector_json(euler_xyz_deg(T.linear()))},
        {"nominal", pose_json(N)},
        {"deviation",
         {{"origin", vector_json(T.translation() - N.translation())},
          {"euler_xyz_deg", vector_json(euler_xyz_deg(T.linear()) - euler_xyz_deg(N.linear()))}}}};
    j["workpiece"]["reference_area"] = truth.reference_area;
    j["fiducials"] = nlohmann::json::object();
    for (const auto& [name, pose] : truth.T_machine_fiducial) j["fiducials"][name] = pose_json(pose);
    j["scans"] = nlohmann::json::array();
    for (const auto& s : truth.scans) {
        nlohmann::json axes = nlohmann::json::object();
        for (const auto& [name, value] : s.axes) axes[name] = value;
        nlohmann::json fid = nlohmann::json::object();
        for (const auto& [name, n] : s.fiducial_points) fid[name] = n;
        j["scans"].push_back({{"file", s.file},
                              {"axes", axes},
                              {"T_machine_scan", matrix_json(s.T_machine_scan)},
                              {"points", s.points},
                              {"outliers", s.outliers},
                              {"workpiece_points", s.workpiece_points},
                              {"reference_points", s.reference_points},
                              {"fiducial_points", fid}});
    }
    write_text_atomically(path, j.dump(2) + "\n");
}

}  // namespace partloc::io
