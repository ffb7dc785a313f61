#pragma once
// Test-only heap guard in the spirit of Drake's LimitMalloc: counts every heap
// allocation (malloc, calloc, realloc, aligned forms, and so operator new) made by any
// thread while a guard is alive. Under AddressSanitizer it uses the sanitizer's
// malloc hooks; otherwise it interposes glibc's allocator entry points.
#include <cstddef>

namespace markcell::test {

class AllocationGuard {
 public:
  AllocationGuard();
  ~AllocationGuard();
  AllocationGuard(const AllocationGuard&) = delete;
  AllocationGuard& operator=(const AllocationGuard&) = delete;
  // Allocations since this guard was made.
  std::size_t allocations() const;
  // Those made by the thread that made the guard: the code under test when other threads
  // (a driver library's receive thread) are outside its control.
  std::size_t allocations_on_this_thread() const;

 private:
  std::size_t start_;
  std::size_t start_this_thread_;
};

}  // namespace markcell::test
