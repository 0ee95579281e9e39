#include "volume/core/huge_pages.h"

#include <sys/mman.h>

#include <algorithm>
#include <cstdlib>

namespace hyb {

namespace {
constexpr size_t kHugePage = size_t(2) << 20;
}  // namespace

namespace detail {

void* hugePageAllocate(size_t bytes) {
  if (bytes < kHugePage) return ::operator new(bytes);
  const size_t size = (bytes + kHugePage - 1) / kHugePage * kHugePage;
  void* p = std::aligned_alloc(kHugePage, size);
  if (!p) throw std::bad_alloc();
  madvise(p, size, MADV_HUGEPAGE);  // a request: without it the buffer still works, with 4 KiB pages
  return p;
}

void hugePageFree(void* p, size_t bytes) noexcept {
  if (bytes < kHugePage) ::operator delete(p);
  else std::free(p);
}

}  // namespace detail

std::shared_ptr<void> hugePageBuffer(size_t bytes) {
  const size_t size = std::max<size_t>(bytes, 1);
  return std::shared_ptr<void>(detail::hugePageAllocate(size), [size](void* p) { detail::hugePageFree(p, size); });
}

}  // namespace hyb
