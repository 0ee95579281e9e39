#include "volume/core/huge_pages.h"

#include <sys/mman.h>

#include <algorithm>
#include <cstdint>

namespace hyb {

namespace {
constexpr size_t kHugePage = size_t(2) << 20;
size_t roundedUp(size_t bytes) { return (bytes + kHugePage - 1) / kHugePage * kHugePage; }
}  // namespace

namespace detail {

// Large blocks are mapped and unmapped here, not taken from malloc's arenas: a freed block goes back
// to the kernel at once, where an arena would keep it (and, 2 MiB-aligned, fragment).
void* hugePageAllocate(size_t bytes) {
  if (bytes < kHugePage) return ::operator new(bytes);
  const size_t size = roundedUp(bytes);
  // Map a page more than asked, then unmap the ends that are not on a 2 MiB boundary.
  void* mapped = mmap(nullptr, size + kHugePage, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (mapped == MAP_FAILED) throw std::bad_alloc();
  const uintptr_t start = reinterpret_cast<uintptr_t>(mapped), aligned = (start + kHugePage - 1) / kHugePage * kHugePage;
  if (aligned > start) munmap(mapped, aligned - start);
  if (const size_t tail = start + size + kHugePage - (aligned + size); tail > 0) munmap(reinterpret_cast<void*>(aligned + size), tail);
  void* p = reinterpret_cast<void*>(aligned);
  madvise(p, size, MADV_HUGEPAGE);  // a request: without it the buffer still works, with 4 KiB pages
  return p;
}

void hugePageFree(void* p, size_t bytes) noexcept {
  if (bytes < kHugePage) ::operator delete(p);
  else munmap(p, roundedUp(bytes));
}

}  // namespace detail

std::shared_ptr<void> hugePageBuffer(size_t bytes) {
  const size_t size = std::max<size_t>(bytes, 1);
  return std::shared_ptr<void>(detail::hugePageAllocate(size), [size](void* p) { detail::hugePageFree(p, size); });
}

}  // namespace hyb
