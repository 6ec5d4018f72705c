// partloc as a library (README, "Use it as a library"): locate the workpiece of a job, then register its
// first scan again by hand. Usage: locate JOB.yaml OUT_DIR; exit 0 located, 3 not located.
#include <cstdio>

#include "partloc/partloc.hpp"

int main(int argc, char** argv) {
    if (argc != 3) return 2;
    // [readme]
    const partloc::Job job = partloc::io::load_job(argv[1]);
    partloc::io::check_job_geometry(job, argv[1]);  // degenerate data refused, as `partloc run` does
    const partloc::JobResult result = partloc::run_job(job);  // RunSettings: threads, seed, config
    partloc::io::write_outputs(argv[2], job, result);
    if (!result.workpiece.valid) {
        std::printf("not located: %s\n", result.workpiece.reason.c_str());
        return 3;
    }
    const Eigen::Vector3d o = result.workpiece.T_machine_workpiece.translation();
    std::printf("located: origin %.3f %.3f %.3f %s\n", o.x(), o.y(), o.z(), job.units.c_str());

    // The parts: the fiducials prepared, and the first scan registered by them alone.
    const partloc::JobPreparation prep = partloc::prepare_job(job);
    const partloc::Scan& scan = job.scans.front();
    std::vector<partloc::PlacedFiducial> placed;
    for (std::size_t k = 0; k < job.fiducials.size(); ++k)
        placed.push_back({job.fiducials[k].name, &prep.models[k],
                          partloc::fiducial_at(job.machine, job.fiducials[k], scan.axes)});
    const partloc::Scale scale = prep.scales.front();
    const auto eye = partloc::estimate_viewpoint(*scan.points, scale.spacing);
    const partloc::PreparedScan prepared = partloc::prepare_scan(*scan.points, scale, prep.sampling, eye);
    const partloc::ScanRegistration reg =
        partloc::register_scan(prepared, placed, partloc::Config{}.candidates);
    std::printf("%s: %s\n", scan.file.c_str(), reg.valid ? "registered" : reg.reason.c_str());
    // [/readme]
    return 0;
}
