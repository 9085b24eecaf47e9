#pragma once
// How the fuzz targets report a broken invariant: a message on stderr, then abort (libFuzzer
// saves the input that did it).

#include <cstdio>
#include <cstdlib>

namespace slam::fuzz {

/// Aborts with `what` when `ok` is false.
inline void Check(bool ok, const char* what) {
  if (ok) return;
  std::fprintf(stderr, "fuzz invariant broken: %s\n", what);
  std::abort();
}

}  // namespace slam::fuzz
