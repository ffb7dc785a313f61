#include "alloc_guard.hpp"

#include <atomic>
#include <cstdlib>
#include <cstring>

namespace {
std::atomic<int> g_armed{0};
std::atomic<std::size_t> g_count{0};
// Static TLS of a plain integer: no allocation and no constructor on first use, so it is
// safe inside malloc itself.
thread_local std::size_t t_count = 0;
inline void on_allocation() {
  if (g_armed.load(std::memory_order_relaxed) > 0) {
    g_count.fetch_add(1, std::memory_order_relaxed);
    ++t_count;
  }
}
}  // namespace

#if defined(__SANITIZE_ADDRESS__)
// Declared by compiler-rt's <sanitizer/allocator_interface.h>, which GCC does not ship;
// GCC's libasan exports the same function.
extern "C" int __sanitizer_install_malloc_and_free_hooks(void (*malloc_hook)(const volatile void*, std::size_t),
                                                         void (*free_hook)(const volatile void*));
namespace {
void malloc_hook(const volatile void*, std::size_t) { on_allocation(); }
void free_hook(const volatile void*) {}
const int g_installed = __sanitizer_install_malloc_and_free_hooks(malloc_hook, free_hook);
}  // namespace
#else
// glibc exports its allocator under __libc_* names; definitions here take precedence
// over libc's for the whole process, so every allocation passes through on_allocation().
extern "C" {
void* __libc_malloc(std::size_t);
void* __libc_calloc(std::size_t, std::size_t);
void* __libc_realloc(void*, std::size_t);
void* __libc_memalign(std::size_t, std::size_t);
void __libc_free(void*);

void* malloc(std::size_t n) {
  on_allocation();
  return __libc_malloc(n);
}
void* calloc(std::size_t n, std::size_t size) {
  on_allocation();
  return __libc_calloc(n, size);
}
void* realloc(void* p, std::size_t n) {
  on_allocation();
  return __libc_realloc(p, n);
}
void free(void* p) { __libc_free(p); }
void* aligned_alloc(std::size_t alignment, std::size_t n) {
  on_allocation();
  return __libc_memalign(alignment, n);
}
void* memalign(std::size_t alignment, std::size_t n) {
  on_allocation();
  return __libc_memalign(alignment, n);
}
int posix_memalign(void** out, std::size_t alignment, std::size_t n) {
  on_allocation();
  void* p = __libc_memalign(alignment, n);
  if (p == nullptr) return 12;  // ENOMEM
  *out = p;
  return 0;
}
}
#endif

namespace markcell::test {

AllocationGuard::AllocationGuard() : start_(g_count.load()), start_this_thread_(t_count) { g_armed.fetch_add(1); }
AllocationGuard::~AllocationGuard() { g_armed.fetch_sub(1); }
std::size_t AllocationGuard::allocations() const { return g_count.load() - start_; }
std::size_t AllocationGuard::allocations_on_this_thread() const { return t_count - start_this_thread_; }

}  // namespace markcell::test
