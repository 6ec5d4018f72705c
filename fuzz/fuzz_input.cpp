// libFuzzer targets for the code that takes input (issue 28): each reader and the job loader. One source,
// one target per reader, chosen by PARTLOC_FUZZ_TARGET (fuzz/CMakeLists.txt). The promise checked is the
// readers' own: a file is read whole or refused with an InputError; any other exception, a crash, a hang or a
// sanitizer's report is a finding.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>

#include "partloc/io/formats.hpp"
#include "partloc/io/job_io.hpp"

namespace fs = std::filesystem;
using namespace partloc::io;

namespace {

/// A private folder for the targets that read through a path (PCD's binary data, the job file).
const fs::path& scratch() {
    static const fs::path dir = [] {
        fs::path d = fs::temp_directory_path() / ("partloc_fuzz_" + std::to_string(::getpid()));
        fs::create_directories(d);
        return d;
    }();
    return dir;
}

fs::path write_scratch(const std::string& name, std::string_view bytes) {
    const fs::path p = scratch() / name;
    std::FILE* f = std::fopen(p.c_str(), "wb");
    if (!f) std::abort();
    std::fwrite(bytes.data(), 1, bytes.size(), f);
    std::fclose(f);
    return p;
}

void run(std::string_view bytes) {
    const std::string name = "fuzz";
#if PARTLOC_FUZZ_TARGET == 1
    detail::parse_ply(bytes, name);
#elif PARTLOC_FUZZ_TARGET == 2
    detail::read_pcd(write_scratch("input.pcd", bytes), bytes, name);
#elif PARTLOC_FUZZ_TARGET == 3
    detail::parse_stl(bytes, name);
#elif PARTLOC_FUZZ_TARGET == 4
    detail::parse_obj(bytes, name);
#elif PARTLOC_FUZZ_TARGET == 5
    detail::parse_columns(bytes, name);
#elif PARTLOC_FUZZ_TARGET == 6
    detail::parse_vtk(bytes, name);
#elif PARTLOC_FUZZ_TARGET == 7
    // The job with the seed corpus's small model and scan beside it, so that a mutated job reaches the
    // geometry checks too.
    static const bool files = [] {
        write_scratch("m.ply",
                      "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                      "property float z\nend_header\n0 0 0\n10 0 0\n0 10 0\n0 0 10\n");
        return true;
    }();
    (void)files;
    load_job(write_scratch("job.yaml", bytes), LoadOptions{1});
#else
#error "PARTLOC_FUZZ_TARGET: 1 ply, 2 pcd, 3 stl, 4 obj, 5 columns, 6 vtk, 7 job"
#endif
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    try {
        run(std::string_view(reinterpret_cast<const char*>(data), size));
    } catch (const InputError&) {
        // Refused with a message: what the readers promise.
    }
    return 0;
}
