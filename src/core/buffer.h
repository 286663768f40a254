// Float arrays that are sized without being zeroed first (frames, cache entries): see
// DefaultInitAllocator.
#pragma once

#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

namespace compose {

// std::allocator, except that value-initialisation (vector(n), resize(n)) leaves floats as they
// are instead of writing zeros: a frame that is about to be filled (read from a file, decoded) is
// not zeroed first, and its pages are first touched by whichever threads fill it. Anything that
// needs zeros asks for them (vector(n, 0.0f), Image(w, h, c)).
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

// Floats sized without zeros (see DefaultInitAllocator): an image's samples, a cache entry.
using FloatBuffer = std::vector<float, DefaultInitAllocator<float>>;

}  // namespace compose
