#include "partloc/io/output_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstring>

namespace partloc::io {

namespace fs = std::filesystem;

bool is_atomic_temporary(const std::string& name) {
    if (name.rfind(".tmp-", 0) != 0) return false;
    std::size_t i = 5;
    for (int field = 0; field < 2; ++field) {
        const std::size_t start = i;
        while (i < name.size() && std::isdigit(static_cast<unsigned char>(name[i]))) ++i;
        if (i == start || i >= name.size() || name[i] != '-') return false;
        ++i;
    }
    return i < name.size();
}

OutputFolderLock::OutputFolderLock(const fs::path& dir) {
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw std::runtime_error(dir.string() + ": cannot be created (" + ec.message() + ")");
    lock_ = dir / ".partloc.lock";
    // The lock file is removed when the run ends (nothing of partloc's own is left in the user's folder). A
    // run that opened it just before the holder removed it would lock a file no longer in the folder, while
    // a third run locks a new one: so the lock counts only when the file locked is still the one at the
    // path; otherwise it is taken again on the new one.
    for (int attempt = 0;; ++attempt) {
        fd_ = ::open(lock_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
        if (fd_ < 0)
            throw std::runtime_error(lock_.string() + ": cannot be created (" + std::strerror(errno) + ")");
        if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
            const int error = errno;
            ::close(fd_);
            fd_ = -1;
            if (error == EWOULDBLOCK)
                throw FolderBusy(dir.string() +
                                 ": another partloc run is writing into this folder; wait for it "
                                 "to finish or choose another --out");
            throw std::runtime_error(lock_.string() + ": cannot be locked (" + std::strerror(error) + ")");
        }
        struct stat held {
        }, named{};
        if (::fstat(fd_, &held) == 0 && ::stat(lock_.c_str(), &named) == 0 && held.st_dev == named.st_dev &&
            held.st_ino == named.st_ino)
            break;
        ::close(fd_);
        fd_ = -1;
        if (attempt == 100)
            throw FolderBusy(dir.string() +
                             ": other partloc runs keep taking this folder; choose another --out");
    }
    // Only now, with the folder ours, are a killed run's temporaries certainly nobody's.
    for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        if (it.depth() > 2) it.disable_recursion_pending();
        std::error_code rm;
        if (it->is_regular_file(rm) && is_atomic_temporary(it->path().filename().string()) &&
            fs::remove(it->path(), rm))
            ++removed_;
    }
}

OutputFolderLock::~OutputFolderLock() {
    if (fd_ < 0) return;
    // Removed while still held, so that no run can hold the same file after it; then closing releases it.
    ::unlink(lock_.c_str());
    ::close(fd_);
}

}  // namespace partloc::io
