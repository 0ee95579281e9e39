// Large buffers on 2 MiB pages: on a virtualised machine a 4 KiB page fault costs about 12 µs
// (docs/scan-conversion.md), so a buffer first touched page by page pays more in faults than in
// writing it; a 2 MiB page takes one fault for 512 of them.
#pragma once

#include <cstddef>
#include <memory>
#include <new>

namespace hyb {

/// An uninitialised buffer of at least @p bytes: from 2 MiB on, a mapping of its own aligned to
/// 2 MiB and backed by 2 MiB pages where the kernel grants them (madvise MADV_HUGEPAGE; without them
/// it works with 4 KiB pages), returned to the kernel when freed; smaller ones from operator new.
/// @throw std::bad_alloc when the memory is not there.
std::shared_ptr<void> hugePageBuffer(size_t bytes);

namespace detail {
void* hugePageAllocate(size_t bytes);
void hugePageFree(void* p, size_t bytes) noexcept;
}  // namespace detail

/// A standard allocator that puts allocations of 2 MiB or more on 2 MiB pages (hugePageBuffer's),
/// smaller ones where operator new does: for vectors that grow to tens of MB a page at a time.
template <class T>
struct HugePageAllocator {
  using value_type = T;
  HugePageAllocator() = default;
  template <class U>
  HugePageAllocator(const HugePageAllocator<U>&) noexcept {}
  T* allocate(size_t n) { return static_cast<T*>(detail::hugePageAllocate(n * sizeof(T))); }
  void deallocate(T* p, size_t n) noexcept { detail::hugePageFree(p, n * sizeof(T)); }
  template <class U>
  bool operator==(const HugePageAllocator<U>&) const noexcept { return true; }
};

}  // namespace hyb
