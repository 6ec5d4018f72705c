#include "partloc/io/result_io.hpp"

#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "partloc/core/geometry.hpp"
#include "partloc/io/atomic_file.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/offsets.hpp"
#include "partloc/io/report_html.hpp"

namespace partloc::io {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;  // keeps SPEC's field order

namespace {

/// Rounded to 1e-9 so that cos(90°) prints as 0, not 6.1e-17; non-finite becomes null.
Json number(double v) {
    if (!std::isfinite(v)) return nullptr;
    const double r = std::round(v * 1e9) / 1e9;
    return r == 0.0 ? 0.0 : r;  // no "-0.0"
}

Json vector3(const Eigen::Vector3d& v) { return Json::array({number(v.x()), number(v.y()), number(v.z())}); }

Json matrix(const Eigen::Isometry3d& T) {
    Json rows = Json::array();
    for (int r = 0; r < 4; ++r) {
        Json row = Json::array();
        for (int c = 0; c < 4; ++c) row.push_back(number(T.matrix()(r, c)));
        rows.push_back(row);
    }
    return rows;
}

Json fit_json(const FiducialFit& f) {
    Json j;
    j["fiducial"] = f.fiducial;
    j["accepted"] = f.valid;
    j["reason"] = f.reason;
    j["T_scan_fiducial"] = matrix(f.T_scan_fiducial);
    j["rmse"] = number(f.rmse);
    j["coverage"] = number(f.coverage);
    j["violation"] = number(f.violation);
    j["conditioning"] = number(f.conditioning);
    j["score"] = number(f.score);
    j["inliers"] = f.inliers;
    j["searched"] = f.searched;
    return j;
}

Json scan_json(const ScanResult& s, const Scan* scan) {
    Json j;
    j["file"] = !s.file.empty() || !scan ? s.file : scan->file;
    j["status"] = s.valid ? "registered" : "rejected";
    j["fiducials"] = s.fiducials;
    j["score"] = number(s.score);
    j["rmse"] = number(s.rmse);
    j["T_machine_scan"] = s.valid ? matrix(s.T_machine_scan) : Json(nullptr);
    j["scale"] = s.valid ? number(s.scale) : Json(nullptr);
    j["scale_centre"] = s.valid ? vector3(s.scale_centre) : Json(nullptr);
    j["scale_sigma"] = s.valid ? number(s.scale_sigma) : Json(nullptr);
    j["message"] = s.reason;
    j["warnings"] = s.warnings;
    Json axes = Json::object();
    if (scan)
        for (const auto& [name, value] : scan->axes) axes[name] = number(value);
    j["axes"] = axes;
    j["points"] = s.points;
    j["point_spacing"] = number(s.point_spacing);
    j["noise"] = number(s.noise);
    j["seconds"] = number(s.seconds);
    Json fits = Json::array();
    for (const auto& f : s.fits) fits.push_back(fit_json(f));
    j["fits"] = fits;
    return j;
}

Json pose_json(const Eigen::Isometry3d& T) {
    Json j;
    j["T_machine_workpiece"] = matrix(T);
    j["origin"] = vector3(T.translation());
    j["euler_xyz_deg"] = vector3(euler_xyz_deg(T.linear()));
    return j;
}

Json workpiece_json(const Job& job, const WorkpieceResult& w) {
    const Eigen::Isometry3d& nominal = job.workpiece.T_machine_workpiece;
    Json j;
    if (w.valid) {
        j = pose_json(w.T_machine_workpiece);
        const Eigen::Vector3d e_loc = euler_xyz_deg(w.T_machine_workpiece.linear());
        const Eigen::Vector3d e_nom = euler_xyz_deg(nominal.linear());
        Eigen::Vector3d de;
        for (int i = 0; i < 3; ++i) de[i] = wrap_deg(e_loc[i] - e_nom[i]);
        const PoseError err = pose_error(w.T_machine_workpiece, nominal);
        j["deviation"] = {{"origin", vector3(w.T_machine_workpiece.translation() - nominal.translation())},
                          {"euler_xyz_deg", vector3(de)},
                          {"translation", number(err.translation)},
                          {"rotation_deg", number(err.rotation_deg)}};
    } else {
        j["T_machine_workpiece"] = nullptr;
        j["origin"] = nullptr;
        j["euler_xyz_deg"] = nullptr;
        j["deviation"] = nullptr;
    }
    j["rmse"] = number(w.rmse);
    j["points"] = w.points;
    j["inliers"] = w.inliers;
    j["located"] = w.valid;
    j["message"] = w.reason;
    j["nominal"] = pose_json(nominal);
    const Uncertainty& u = w.uncertainty;
    if (u.available) {
        j["uncertainty_95"] = {{"origin", vector3(u.origin)}, {"euler_xyz_deg", vector3(u.euler_deg)}};
        j["uncertainty_parts"] = {
            {"sigma_from_scans",
             {{"origin", vector3(u.origin_scans)}, {"euler_xyz_deg", vector3(u.euler_scans)}}},
            {"sigma_from_probing",
             {{"origin", vector3(u.origin_probing)}, {"euler_xyz_deg", vector3(u.euler_probing)}}},
            {"sigma_of_probing_in_scans",
             {{"origin", vector3(u.origin_probing_in_scans)},
              {"euler_xyz_deg", vector3(u.euler_probing_in_scans)}}},
            {"sigma_from_noise",
             {{"origin", vector3(u.origin_noise)}, {"euler_xyz_deg", vector3(u.euler_noise)}}},
            {"scans", u.scans}};
    } else {
        j["uncertainty_95"] = nullptr;  // fewer than three registered scans: no honest estimate
    }
    j["fit"] = w.fit;
    Json datums = Json::array();
    for (const auto& d : w.datums)
        datums.push_back({{"name", d.name}, {"points", d.points}, {"rmse", number(d.rmse)}});
    j["datums"] = datums;
    return j;
}

/// Poses the job gave as probed points, with each plane's fit (what the probing says of itself).
Json probed_json(const Job& job) {
    Json all = Json::array();
    for (const auto& p : job.probed_poses) {
        Json planes = Json::array();
        for (const auto& f : p.frame.planes)
            planes.push_back({{"points", f.points}, {"rms", number(f.rms)}, {"max", number(f.max)}});
        all.push_back({{"field", p.field},
                       {"origin", vector3(p.frame.T.translation())},
                       {"euler_xyz_deg", vector3(euler_xyz_deg(p.frame.T.linear()))},
                       {"planes", planes},
                       {"nonorthogonality_deg", number(p.frame.nonorthogonality_deg)}});
    }
    return all;
}

Json face_allowance_json(const FaceAllowance& f) {
    Json j;
    j["min"] = number(f.min);
    j["min_at"] = std::isnan(f.min) ? Json(nullptr) : vector3(f.min_at);
    j["mean"] = number(f.mean);
    j["max"] = number(f.max);
    j["unscanned_fraction"] = number(f.unscanned_fraction());
    j["samples"] = f.samples;
    return j;
}

/// SPEC "Machining": allowance and placement; nothing without a final part.
void machining_json(Json& j, const JobResult& result) {
    const MachiningResult& m = result.machining;
    if (!m.available) {
        if (!m.reason.empty()) j["allowance"] = {{"message", m.reason}};
        return;
    }
    Json a = face_allowance_json(m.map.all);
    a["required"] = number(m.required);
    a["located_min"] = number(m.located.all.min);
    Json faces = Json::array();
    for (std::size_t f = 0; f < m.map.faces.size(); ++f) {
        Json fj = {
            {"id", m.part.faces[f].id}, {"name", m.face_names[f]}, {"area", number(m.part.faces[f].area)}};
        fj.update(face_allowance_json(m.map.faces[f]));
        faces.push_back(fj);
    }
    a["faces"] = faces;
    j["allowance"] = a;
    Json p;
    p["mode"] = m.maxmin ? "maxmin" : "located";
    p["status"] = m.fits ? "fits" : "insufficient_stock";
    p["message"] = m.placement_reason;
    p["T_machine_part"] = matrix(m.T_machine_part);
    p["origin"] = vector3(m.T_machine_part.translation());
    p["euler_xyz_deg"] = vector3(euler_xyz_deg(m.T_machine_part.linear()));
    p["min_allowance"] = number(m.map.all.min);
    p["min_at"] = vector3(m.map.all.min_at);
    p["min_face"] = m.map.min_face >= 0 ? Json(m.face_names[m.map.min_face]) : Json(nullptr);
    p["moved_from_located"] = {{"translation", number(m.translation)},
                               {"rotation_deg", number(m.rotation_deg)}};
    p["seconds"] = number(m.seconds);
    if (m.maxmin) p["search_seconds"] = number(m.placement_seconds);
    j["placement"] = p;
}

/// allowance.ply: the final part's samples where it is placed (machine frame), binary little-endian, with
/// `allowance` (NaN where unscanned), `scanned` (0 or 1) and a colour: red where the part breaks out, grey
/// where unscanned, green to blue as the allowance grows to twice its mean.
void write_allowance_ply(const fs::path& path, const MachiningResult& m, const std::string& comment) {
    const AllowanceMap& map = m.map;
    std::string header =
        "ply\nformat binary_little_endian 1.0\ncomment partloc allowance " + comment + "\nelement vertex " +
        std::to_string(map.points.size()) +
        "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty "
        "float ny\nproperty float nz\nproperty float allowance\nproperty uchar scanned\nproperty "
        "uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
    std::string body;
    body.reserve(map.points.size() * 32);
    const auto put = [&](float v) { body.append(reinterpret_cast<const char*>(&v), sizeof v); };
    const double top = std::isfinite(map.all.mean) && map.all.mean > 0 ? 2.0 * map.all.mean : 1.0;
    for (std::size_t i = 0; i < map.points.size(); ++i) {
        for (int k = 0; k < 3; ++k) put(static_cast<float>(map.points[i][k]));
        for (int k = 0; k < 3; ++k) put(static_cast<float>(map.normals[i][k]));
        const double a = map.allowance[i];
        put(static_cast<float>(a));
        unsigned char c[4] = {0, 128, 128, 128};
        if (!std::isnan(a)) {
            c[0] = 1;
            if (a < m.required) {
                c[1] = 220, c[2] = 30, c[3] = 30;
            } else {
                const double t = std::clamp(a / top, 0.0, 1.0);
                c[1] = 20, c[2] = static_cast<unsigned char>(200 * (1 - t) + 40),
                c[3] = static_cast<unsigned char>(215 * t + 40);
            }
        }
        body.append(reinterpret_cast<const char*>(c), 4);
    }
    write_text_atomically(path, header + body);
}

/// JSON text with every array of plain numbers on one line, so a 4x4 matrix reads as four rows.
std::string compact_number_arrays(const std::string& text) {
    std::string out;
    out.reserve(text.size());
    bool in_string = false;
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (in_string) {
            if (text[i] == '\\')
                out += text[i++];  // the escaped character follows as it is
            else if (text[i] == '"')
                in_string = false;
        } else if (text[i] == '"') {
            in_string = true;
        } else if (text[i] == '[') {
            const std::size_t end = text.find_first_of("[]{\"", i + 1);
            if (end != std::string::npos && text[end] == ']') {
                out += '[';
                bool space = false;
                for (std::size_t k = i + 1; k < end; ++k) {
                    const char c = text[k];
                    if (c == ' ' || c == '\n') {
                        space = true;
                        continue;
                    }
                    if (space && out.back() == ',') out += ' ';
                    space = false;
                    out += c;
                }
                out += ']';
                i = end;
                continue;
            }
        }
        out += text[i];
    }
    return out;
}

/// Removes a file of an earlier run that this run does not produce, so the folder tells one story.
void remove_stale(const fs::path& path) {
    std::error_code ec;
    fs::remove(path, ec);
}

/// The frame the CAM programme is written in: the placed frame where the final part was placed, else the
/// located workpiece frame; the frame the work offsets give the controller.
const Eigen::Isometry3d& cam_frame(const JobResult& result) {
    return result.machining.available ? result.machining.T_machine_part
                                      : result.workpiece.T_machine_workpiece;
}

bool has_cam_models(const JobResult& result) {
    return result.workpiece.valid && (result.stock || result.machining.available);
}

/// DIR/cam/stock.stl and DIR/cam/final_part.stl: the stock and the placed final part in cam_frame, so that
/// a CAM programme written about them, run with the work offsets, cuts the part where it lies in the
/// material. Earlier runs' copies are removed when this run has none.
std::vector<fs::path> write_cam_models(const fs::path& out_dir, const JobResult& result,
                                       const std::string& units) {
    const fs::path dir = out_dir / "cam";
    const fs::path stock = dir / "stock.stl", part = dir / "final_part.stl";
    std::vector<fs::path> written;
    if (!has_cam_models(result)) {
        remove_stale(stock);
        remove_stale(part);
        std::error_code ec;
        fs::remove(dir, ec);  // only when empty
        return written;
    }
    fs::create_directories(dir);
    const Eigen::Matrix4d T_frame_machine = cam_frame(result).inverse().matrix();
    const std::string comment = units + ", workpiece frame";
    const auto write_in_frame = [&](const fs::path& path,
                                    const std::shared_ptr<open3d::geometry::TriangleMesh>& mesh) {
        if (!mesh) {
            remove_stale(path);
            return;
        }
        open3d::geometry::TriangleMesh m = *mesh;
        m.Transform(T_frame_machine);
        write_mesh(path, m, comment);
        written.push_back(path);
    };
    write_in_frame(stock, result.stock);
    write_in_frame(part, result.machining.available ? result.machining.final_part_placed : nullptr);
    return written;
}

void cam_json(Json& j, const JobResult& result) {
    if (!has_cam_models(result)) return;
    Json c;
    c["frame"] = result.machining.available ? "placement.T_machine_part" : "workpiece.T_machine_workpiece";
    c["T_machine_frame"] = matrix(cam_frame(result));
    c["stock"] = result.stock ? Json("cam/stock.stl") : Json(nullptr);
    c["final_part"] = result.machining.available ? Json("cam/final_part.stl") : Json(nullptr);
    j["cam"] = c;
}

}  // namespace

std::string result_json(const Job& job, const JobResult& result) {
    Json j;
    j["status"] = result.workpiece.valid ? "located" : "not_located";
    j["units"] = job.units;
    Json scans = Json::array();
    for (std::size_t i = 0; i < result.scans.size(); ++i)
        scans.push_back(scan_json(result.scans[i], i < job.scans.size() ? &job.scans[i] : nullptr));
    j["scans"] = scans;
    j["workpiece"] = workpiece_json(job, result.workpiece);
    j["probed_poses"] = probed_json(job);
    j["warnings"] = result.warnings;
    machining_json(j, result);
    cam_json(j, result);
    if (!job.output.offsets.empty()) j["offsets"] = Json::parse(work_offsets_json(job, result));
    j["seconds"] = number(result.seconds);
    // A file name need not be UTF-8 (a path is bytes); JSON must be. Bytes that are not UTF-8 are written as
    // U+FFFD, rather than the writer throwing and the run failing at its last step.
    return compact_number_arrays(j.dump(2, ' ', false, Json::error_handler_t::replace)) + "\n";
}

std::vector<fs::path> write_outputs(const fs::path& out_dir, const Job& job, const JobResult& result,
                                    const std::string& job_name) {
    fs::create_directories(out_dir);
    // The earlier run's result.json goes first: should this run fail half way (a full disk), the folder holds
    // some of its files and no result.json, never an older result.json beside a newer report. A result.json
    // in the folder therefore always belongs to the files beside it.
    {
        std::error_code ec;
        fs::remove(out_dir / "result.json", ec);
        if (ec)
            throw std::runtime_error((out_dir / "result.json").string() + ": cannot be replaced (" +
                                     ec.message() + ")");
    }
    const std::string units = "units " + job.units;
    // The files side by side (seed 106: the three models 12-13 ms, the report 8-9 ms, one after another),
    // result.json last, once the others are written; `written` in this order whatever finishes first.
    const fs::path files[] = {out_dir / "merged.ply", out_dir / "stock.stl",
                              out_dir / "final_part_located.stl", out_dir / "report.html"};
    bool made[4] = {false, false, false, true};
    const auto model = [&](int k, const auto& geometry, auto write) {
        if (geometry) {
            write(files[k], *geometry, units);
            made[k] = true;
        } else {
            remove_stale(files[k]);
        }
    };
    tbb::parallel_invoke([&] { model(0, result.merged, write_point_cloud); },
                         [&] { model(1, result.stock, write_mesh); },
                         [&] { model(2, result.final_part_located, write_mesh); },
                         [&] {
                             ReportOptions options;
                             options.job_name = job_name;
                             write_text_atomically(files[3], render_report_html(job, result, options));
                         });
    std::vector<fs::path> written;
    for (int k = 0; k < 4; ++k)
        if (made[k]) written.push_back(files[k]);

    // The machining outputs (SPEC "Machining"): there only when this run measured them.
    if (result.machining.available) {
        write_allowance_ply(out_dir / "allowance.ply", result.machining, units);
        written.push_back(out_dir / "allowance.ply");
        write_mesh(out_dir / "final_part_placed.stl", *result.machining.final_part_placed, units);
        written.push_back(out_dir / "final_part_placed.stl");
    } else {
        remove_stale(out_dir / "allowance.ply");
        remove_stale(out_dir / "final_part_placed.stl");
    }
    for (const auto& f : write_cam_models(out_dir, result, units)) written.push_back(f);
    for (const auto& f : write_work_offsets(out_dir, job, result)) written.push_back(f);
    write_text_atomically(out_dir / "result.json", result_json(job, result));
    written.push_back(out_dir / "result.json");
    return written;
}

}  // namespace partloc::io
