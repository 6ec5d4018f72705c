#pragma once
// report.html: one self-contained page (no scripts, fonts or images from elsewhere) for the machinist:
// the job, each scan's outcome and every fiducial tried, the located workpiece pose against the nominal,
// a 3D view (io/report_view3d.hpp; three.js inlined), and orthographic pictures (top XY, front XZ, side YZ)
// of the merged workpiece points with the located and nominal workpiece frames, as inline SVG.
#include <string>

#include "partloc/io/report_view3d.hpp"
#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc::io {

struct ReportOptions {
    std::string job_name;           ///< the job file as the user named it; shown in the title
    std::size_t max_points = 4000;  ///< merged points drawn per picture (an even subsample of them)
    View3dOptions view3d;
};

/// The page as text. Every string taken from the job or its files is HTML-escaped.
std::string render_report_html(const Job& job, const JobResult& result, const ReportOptions& options = {});

/// `text` with & < > " ' replaced by their HTML entities.
std::string escape_html(const std::string& text);

}  // namespace partloc::io
