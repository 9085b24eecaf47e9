#pragma once
// The engine's one way to run independent items across threads.

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cstddef>

namespace slam {

/// Runs body(i) for i in [0, n), across threads (oneTBB) or in order; each i must be independent,
/// so that both give the same results.
template <typename Body>
void ForEach(bool parallel, size_t n, const Body& body) {
  if (parallel && n > 1) {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t i = r.begin(); i != r.end(); ++i) body(i);
    });
  } else {
    for (size_t i = 0; i < n; ++i) body(i);
  }
}

}  // namespace slam
