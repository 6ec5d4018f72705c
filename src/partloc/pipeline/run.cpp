#include "partloc/pipeline/run.hpp"

namespace partloc {

JobResult run_job(const Job& job, const RunSettings& settings) {
    JobResult result;  // TEMPORARY stub while the pipeline is being written
    result.units = job.units;
    result.workpiece.message = "pipeline not yet implemented";
    return result;
}

}  // namespace partloc
