#pragma once
// Which mutex guards which member, checked at compile time by Clang's thread-safety analysis
// (-Wthread-safety, on for every Clang build of ours: cmake/warnings.cmake; the fuzz build of
// scripts/fuzz is one). With other compilers the annotations are empty.
//
// Members a mutex guards are declared SLAM_GUARDED_BY(mutex_); functions that expect it held
// SLAM_REQUIRES(mutex_). Lock with MutexLock (std::lock_guard and std::unique_lock are not
// annotated in libstdc++, so the analysis would not see them). Wait on a condition variable
// through the lock (MutexLock::WaitUntil) in a loop that tests the condition itself, so that
// the analysis sees the condition read under the lock.

#include <chrono>
#include <condition_variable>
#include <mutex>

#if defined(__clang__)
#define SLAM_THREAD_ANNOTATION(x) __attribute__((x))
#else
#define SLAM_THREAD_ANNOTATION(x)
#endif

#define SLAM_CAPABILITY(name) SLAM_THREAD_ANNOTATION(capability(name))
#define SLAM_SCOPED_CAPABILITY SLAM_THREAD_ANNOTATION(scoped_lockable)
#define SLAM_GUARDED_BY(mutex) SLAM_THREAD_ANNOTATION(guarded_by(mutex))
#define SLAM_PT_GUARDED_BY(mutex) SLAM_THREAD_ANNOTATION(pt_guarded_by(mutex))
#define SLAM_REQUIRES(...) SLAM_THREAD_ANNOTATION(requires_capability(__VA_ARGS__))
#define SLAM_EXCLUDES(...) SLAM_THREAD_ANNOTATION(locks_excluded(__VA_ARGS__))
#define SLAM_ACQUIRE(...) SLAM_THREAD_ANNOTATION(acquire_capability(__VA_ARGS__))
#define SLAM_RELEASE(...) SLAM_THREAD_ANNOTATION(release_capability(__VA_ARGS__))

namespace slam {

/// std::mutex, annotated as a capability.
class SLAM_CAPABILITY("mutex") Mutex {
 public:
  Mutex() = default;
  Mutex(const Mutex&) = delete;
  Mutex& operator=(const Mutex&) = delete;

  void lock() SLAM_ACQUIRE() { mutex_.lock(); }
  void unlock() SLAM_RELEASE() { mutex_.unlock(); }

 private:
  friend class MutexLock;
  std::mutex mutex_;
};

/// Holds a Mutex for its scope (std::unique_lock underneath, for condition variables).
class SLAM_SCOPED_CAPABILITY MutexLock {
 public:
  explicit MutexLock(Mutex& mutex) SLAM_ACQUIRE(mutex) : lock_(mutex.mutex_) {}
  ~MutexLock() SLAM_RELEASE() {}
  MutexLock(const MutexLock&) = delete;
  MutexLock& operator=(const MutexLock&) = delete;

  /// Releases the mutex while waiting on `cv`, until notified, `deadline` or a spurious wake-up;
  /// holds it again on return. Callers loop on their own condition.
  template <typename Clock, typename Duration>
  std::cv_status WaitUntil(std::condition_variable& cv,
                           const std::chrono::time_point<Clock, Duration>& deadline) {
    return cv.wait_until(lock_, deadline);
  }

 private:
  std::unique_lock<std::mutex> lock_;
};

}  // namespace slam
