#include "partloc/io/result_io.hpp"

#include <tbb/parallel_invoke.h>

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

    for (const auto& f : write_work_offsets(out_dir, job, result)) written.push_back(f);
    write_text_atomically(out_dir / "result.json", result_json(job, result));
    written.push_back(out_dir / "result.json");
    return written;
}

}  // namespace partloc::io
