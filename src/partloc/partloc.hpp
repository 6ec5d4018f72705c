#pragma once
// partloc as a library: this one header, and the CMake target partloc::partloc.
//
// Two levels (examples/locate.cpp uses both):
// - a whole job: io::load_job reads job.yaml and its files, io::check_job_geometry refuses degenerate data
//   (planar scans, tiny fiducials: what partloc run refuses), run_job locates the workpiece,
//   io::write_outputs writes result.json, merged.ply, stock.stl and report.html;
// - the parts: prepare_job (every scan's scale, the fiducials' prepared models), prepare_scan and
//   register_scan (one scan by the fiducials placed at its axis values), fit_reference_surfaces (the part
//   from registered points, machine0).
// Frames and units: core/geometry.hpp. Every tuning constant: pipeline/config.hpp (RunSettings::config).
#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/localize.hpp"
#include "partloc/core/register_scan.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/core/workpiece_fit.hpp"
#include "partloc/io/cloud_io.hpp"
#include "partloc/io/input_error.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/offsets.hpp"
#include "partloc/io/result_io.hpp"
#include "partloc/pipeline/config.hpp"
#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"
#include "partloc/pipeline/run.hpp"
