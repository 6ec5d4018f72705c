#include "partloc/io/atomic_file.hpp"

#include <unistd.h>

#include <atomic>
#include <fstream>
#include <stdexcept>

namespace partloc::io {

namespace fs = std::filesystem;

void write_atomically(const fs::path& path, const std::function<bool(const fs::path&)>& write) {
    static std::atomic<unsigned> counter{0};
    if (path.has_parent_path()) fs::create_directories(path.parent_path());
    // Keep the extension last: writers such as Open3D's choose the format from it.
    const fs::path tmp = path.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-" +
                                               std::to_string(counter++) + "-" + path.filename().string());
    bool ok = false;
    try {
        ok = write(tmp);
    } catch (...) {
        std::error_code ec;
        fs::remove(tmp, ec);
        throw;
    }
    std::error_code ec;
    if (!ok || !fs::exists(tmp)) {
        fs::remove(tmp, ec);
        throw std::runtime_error(path.string() + ": could not be written");
    }
    fs::rename(tmp, path, ec);
    if (ec) {
        fs::remove(tmp, ec);
        throw std::runtime_error(path.string() + ": could not be written (" + ec.message() + ")");
    }
}

void write_text_atomically(const fs::path& path, const std::string& text) {
    write_atomically(path, [&](const fs::path& tmp) {
        std::ofstream out(tmp, std::ios::binary);
        out << text;
        out.close();
        return static_cast<bool>(out);
    });
}

}  // namespace partloc::io
