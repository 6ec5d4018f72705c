// The program's operator new: blocks of 256 KB and more are marked for transparent huge pages
// (madvise MADV_HUGEPAGE); every block still comes from malloc and goes back to free.
//
// Why: a scan's points, grids and fits are arrays of megabytes, and every 4 KB page of them is a page fault
// when first touched (a job of six scans of 250 k points made 55 thousand, of 2 M points 420 thousand; on the
// virtual machines we run on, a fault is dear). On 2 MB pages they are up to 512 times fewer, and the
// processor's address cache misses less. glibc's own switch for this (GLIBC_TUNABLES=glibc.malloc.hugetlb=1)
// is read when the process starts and cannot be set from inside it.
//
// Measured (the same binary with PARTLOC_LARGE_PAGES=0 and without, alternating; BENCHMARK.md, "Huge pages
// for large blocks"): seed 106, five rounds, 2.01 s against 2.07 s (page faults 34 k against 55 k; glibc's
// switch 2.00 s; marking from 1 MB, 2.04 s); six scans of 2 M points, two rounds, 6.42-6.66 s
// against 7.02-7.33 s (faults 141 k against 424 k; glibc's switch 5.97-6.19 s). Blocks mapped on their own
// with a header to tell them apart at delete gained less (2.05 s against 2.09 s in their rounds). The results
// are the same bits: only the pages under the memory change.
//
// PARTLOC_LARGE_PAGES=0 in the environment turns the marking off. Linked into the executables only (an object
// library), never into the static libraries that a user of the library links: a program decides its own
// allocator. Left out under the address and thread sanitizers, which bring their own operator new.
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)

#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>

namespace {

constexpr std::size_t kLarge = std::size_t(1) << 18;  // blocks from this size are marked
constexpr std::size_t kMalloc = 16;                   // malloc's own alignment

bool marking_on() {
    static const bool on = [] {
        const char* e = std::getenv("PARTLOC_LARGE_PAGES");
        return !(e && std::strcmp(e, "0") == 0);
    }();
    return on;
}

// Marks the whole pages of [p, p + n) for huge pages: the kernel backs each 2 MB-aligned stretch of them
// with one page when it is first touched (the neighbours within those pages are malloc's, and only gain).
void mark(void* p, std::size_t n) noexcept {
    if (n < kLarge || !marking_on()) return;
    static const std::uintptr_t page = static_cast<std::uintptr_t>(sysconf(_SC_PAGESIZE));
    const std::uintptr_t a = reinterpret_cast<std::uintptr_t>(p);
    const std::uintptr_t first = a & ~(page - 1), last = (a + n + page - 1) & ~(page - 1);
    madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);  // a hint; failure is harmless
}

void* allocate(std::size_t n, std::size_t align) noexcept {
    void* p = nullptr;
    if (align <= kMalloc)
        p = std::malloc(n);
    else if (posix_memalign(&p, align, n) != 0)
        p = nullptr;
    if (p) mark(p, n);
    return p;
}

void* allocate_or_throw(std::size_t n, std::size_t align) {
    if (n == 0) n = 1;
    for (;;) {
        if (void* p = allocate(n, align)) return p;
        const std::new_handler handler = std::get_new_handler();
        if (!handler) throw std::bad_alloc();
        handler();
    }
}

void* allocate_or_null(std::size_t n, std::size_t align) noexcept {
    try {
        return allocate_or_throw(n, align);
    } catch (...) {
        return nullptr;
    }
}

std::size_t alignment(std::align_val_t a) {
    const auto v = static_cast<std::size_t>(a);
    return v > kMalloc ? v : kMalloc;
}

}  // namespace

void* operator new(std::size_t n) { return allocate_or_throw(n, kMalloc); }
void* operator new[](std::size_t n) { return allocate_or_throw(n, kMalloc); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept { return allocate_or_null(n, kMalloc); }
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept { return allocate_or_null(n, kMalloc); }
void* operator new(std::size_t n, std::align_val_t a) { return allocate_or_throw(n, alignment(a)); }
void* operator new[](std::size_t n, std::align_val_t a) { return allocate_or_throw(n, alignment(a)); }
void* operator new(std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
    return allocate_or_null(n, alignment(a));
}
void* operator new[](std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
    return allocate_or_null(n, alignment(a));
}

void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }

#endif
