#pragma once
// Keeping `keep` of `total` items evenly spaced in their order (a scan's readings checked, a
// multiscan's readings searched): item k is kept when it starts a new share of total / keep.

#include <cstddef>

namespace slam {

/// Whether item `k` of `total` is one of `keep` evenly spaced ones (every item when keep >=
/// total). Precondition: k < total.
inline bool KeptEvenly(size_t k, size_t keep, size_t total) {
  return keep >= total || (k * keep) / total != ((k + 1) * keep) / total;
}

}  // namespace slam
