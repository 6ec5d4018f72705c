#include "partloc/pipeline/job.hpp"

#include <stdexcept>

namespace partloc {

double millimetres_per_unit(const std::string& units) {
    if (units == "mm") return 1.0;
    if (units == "m") return 1000.0;
    if (units == "in") return 25.4;
    if (units == "cm") return 10.0;
    if (units == "um") return 0.001;
    throw std::invalid_argument("unknown unit '" + units + "' (known: mm, m, in, cm, um)");
}

}  // namespace partloc
