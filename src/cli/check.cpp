// `partloc check JOB` (issue 27): the job and its files loaded and checked as `run` would, what a run
// would do printed, and the warnings that can be seen without registering a scan.
#include <open3d/utility/Logging.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "commands.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/pipeline/job_checks.hpp"

namespace partloc::cli {

namespace {

std::string number(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4g", v);
    return b;
}

std::string model_line(const ModelSource& m, const std::string& units) {
    std::ostringstream s;
    s << m.file << ": ";
    if (m.mesh)
        s << "mesh of " << m.mesh->triangles_.size() << " triangles";
    else if (m.points)
        s << m.points->points_.size() << " points";
    const Eigen::AlignedBox3d box = bounding_box(m);
    if (!box.isEmpty()) {
        const Eigen::Vector3d d = box.sizes();
        s << ", " << number(d.x()) << " x " << number(d.y()) << " x " << number(d.z()) << " " << units;
    }
    return s.str();
}

std::string origin(const Eigen::Isometry3d& T) {
    const Eigen::Vector3d o = T.translation();
    return "[" + number(o.x()) + ", " + number(o.y()) + ", " + number(o.z()) + "]";
}

std::string axes_text(const AxisValues& q) {
    if (q.empty()) return "all axes at 0";
    std::string s;
    for (const auto& [name, value] : q) s += (s.empty() ? "" : ", ") + name + " = " + number(value);
    return s;
}

}  // namespace

int command_check(const std::string& job_file) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    Job job;
    try {
        job = io::load_job(job_file);
        io::check_job_geometry(job, job_file);
    } catch (const io::InputError& e) {
        std::string line = e.what();
        for (char& c : line)
            if (c == '\n' || c == '\r') c = ' ';
        std::cerr << "partloc: " << line << std::endl;
        return 2;
    } catch (const std::exception& e) {
        std::cerr << "partloc: " << job_file << ": " << e.what() << std::endl;
        return 2;
    }
    const std::string& u = job.units;
    std::ostringstream out;
    out << "partloc check: " << job_file << ": the job and its files are readable\n";
    out << "units: " << u << "\n";
    out << "scanner: point spacing "
        << (job.scanner.point_spacing ? number(*job.scanner.point_spacing) + " " + u
                                      : "measured on each scan")
        << ", noise " << (job.scanner.noise ? number(*job.scanner.noise) + " " + u : "measured on each scan")
        << "\n";
    if (job.machine.axes.empty()) {
        out << "machine axes: none\n";
    } else {
        out << "machine axes:";
        for (const Axis& a : job.machine.axes)
            out << " " << a.name << " (" << (a.type == AxisType::Rotary ? "rotary" : "linear") << ")";
        out << "\n";
    }
    out << "fiducials: " << job.fiducials.size() << "\n";
    for (const Fiducial& f : job.fiducials)
        out << "  " << f.name << "  " << model_line(f.model, u) << "; probed at "
            << origin(f.T_machine_fiducial)
            << (f.moves_with.empty() ? "" : ", moves with " + f.moves_with.front()) << "\n";
    const Workpiece& w = job.workpiece;
    out << "workpiece:\n  reference surfaces  " << model_line(w.reference_surfaces, u) << "\n";
    if (w.final_part) out << "  final part  " << model_line(*w.final_part, u) << "\n";
    out << "  nominal datum origin " << origin(w.T_machine_workpiece) << "; fit "
        << (w.fit == WorkpieceFitMode::Datums ? "datums (3-2-1)" : "simultaneous")
        << (w.moves_with.empty() ? "" : "; moves with " + w.moves_with.front()) << "\n";
    if (w.final_part)
        out << "  placement " << (w.placement.maxmin ? "maxmin" : "located") << ", allowance required "
            << number(w.allowance_min.value_or(0.0)) << " " << u << "\n";
    const std::vector<ScanSummary> scans = summarise_scans(job);
    out << "scans: " << job.scans.size() << "\n";
    for (std::size_t i = 0; i < job.scans.size(); ++i)
        out << "  " << job.scans[i].file << "  " << scans[i].points << " points, spacing "
            << number(scans[i].spacing) << " " << u << ", spanning " << number(scans[i].extent) << " " << u
            << "; " << axes_text(job.scans[i].axes) << "\n";
    if (!job.output.offsets.empty()) {
        out << "work offsets:";
        for (const std::string& d : job.output.offsets) out << " " << d;
        out << " (work offset " << job.output.work_offset << ")\n";
    }
    std::vector<std::string> warnings = job.warnings;
    for (const std::string& s : unit_warnings(job, scans)) warnings.push_back(s);
    for (const std::string& s : symmetry_warnings(job)) warnings.push_back(s);
    if (warnings.empty()) {
        out << "warnings: none that can be seen before the scans are registered\n";
    } else {
        out << "warnings: " << warnings.size() << "\n";
        for (const std::string& s : warnings) out << "  " << s << "\n";
    }
    std::cout << out.str() << std::flush;
    return 0;
}

}  // namespace partloc::cli
