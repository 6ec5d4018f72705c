#pragma once
// report.html's 3D view (issues 26, 27): the registered workpiece points coloured by scan or by their
// deviation from the located reference surfaces, the reference surfaces where they were located, the
// located and nominal workpiece frames, and the final part's allowance as a colour map (red where it breaks
// out, grey where unscanned). Drawn by three.js from Debian's libjs-three with its OrbitControls, both
// inlined so that the page stays one file and opens without a network; the data are base64 arrays in the
// page. Without three.js on the machine the section says so and the page is otherwise the same.
#include <filesystem>
#include <string>

#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc::io {

struct View3dOptions {
    /// Where three.min.js and examples/js/controls/OrbitControls.js are: $PARTLOC_THREE_JS_DIR when set,
    /// else the build's (Debian's /usr/share/javascript/three).
    std::filesystem::path three_js_dir = default_three_js_dir();
    /// Reference-surface triangles drawn at most (a larger mesh is drawn as its vertices).
    std::size_t max_triangles = 200000;
    /// Allowance samples drawn at most (an even subsample).
    std::size_t max_allowance_points = 60000;

    static std::filesystem::path default_three_js_dir();
};

/// The section's HTML (heading, canvas, controls, legend, data and scripts). The element with id `view3d`
/// carries, once the script has run, `data-drawn` (pixels of the first frame that are not background) or
/// `data-error` (the script's error): what the browser test reads.
std::string view3d_section(const Job& job, const JobResult& result, const View3dOptions& options = {});

}  // namespace partloc::io
