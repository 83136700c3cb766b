// What an Embree device's callbacks share with the code that builds a scene on it (the fiber scene, a client's
// mesh): the bytes Embree holds, bounded by a limit while building; the caller's stop predicate, asked by the
// memory and progress monitors; and the first error Embree reported. One device per scene, so the monitor sees
// that scene's allocations alone. Heap-allocate it: the callbacks keep its address, and release the device
// before it.
#pragma once

#include <embree3/rtcore.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

namespace loomlight::yarn {

inline const char* EmbreeErrorName(RTCError e) {
  switch (e) {
    case RTC_ERROR_NONE:
      return "none";
    case RTC_ERROR_UNKNOWN:
      return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT:
      return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION:
      return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY:
      return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU:
      return "unsupported CPU";
    case RTC_ERROR_CANCELLED:
      return "cancelled";
  }
  return "error";
}

struct EmbreeBuildMonitor {
  std::atomic<int64_t> current{0};
  std::atomic<int64_t> peak{0};
  int64_t limit = 0;
  std::string limit_name;                     // the caller's name for `limit`, for the over-limit message
  std::string cancelled_status = "cancelled";  // what Status says once the predicate said stop
  std::atomic<bool> building{false};          // the limit and the cancel predicate apply only while building
  const std::function<bool()>* cancel = nullptr;
  std::atomic<bool> cancelled{false};
  std::atomic<bool> over_limit{false};
  std::mutex mu;
  int64_t refused_bytes = 0;  // the first refused allocation
  int64_t refused_total = 0;  // the total it would have made
  RTCError error = RTC_ERROR_NONE;
  std::string error_message;

  // The device's error and memory callbacks, pointed at this monitor.
  void Attach(RTCDevice device) {
    rtcSetDeviceErrorFunction(device, &EmbreeBuildMonitor::OnError, this);
    rtcSetDeviceMemoryMonitorFunction(device, &EmbreeBuildMonitor::OnMemory, this);
  }

  bool ShouldCancel() {
    if (cancelled.load(std::memory_order_relaxed)) return true;
    if (cancel == nullptr || !*cancel) return false;
    bool stop = true;  // a predicate that throws cannot say "go on"; nothing may unwind through Embree
    try {
      stop = (*cancel)();
    } catch (...) {
    }
    if (stop) cancelled.store(true, std::memory_order_relaxed);
    return stop;
  }

  void RaisePeak(int64_t now) {
    int64_t p = peak.load(std::memory_order_relaxed);
    while (now > p && !peak.compare_exchange_weak(p, now, std::memory_order_relaxed)) {
    }
  }

  // Embree's contract: bytes > 0 before an allocation (post = false; returning false cancels it, and it must
  // then not be counted) or after one that already happened (post = true, counted whatever we return);
  // bytes < 0 for a release. Called from Embree's threads concurrently.
  static bool OnMemory(void* ptr, ssize_t bytes, bool post) {
    auto* m = static_cast<EmbreeBuildMonitor*>(ptr);
    const int64_t b = static_cast<int64_t>(bytes);
    if (b > 0 && !post && m->building.load(std::memory_order_relaxed)) {
      if (m->ShouldCancel()) return false;
      const int64_t after = m->current.fetch_add(b, std::memory_order_relaxed) + b;
      if (after > m->limit) {
        m->current.fetch_sub(b, std::memory_order_relaxed);
        std::lock_guard<std::mutex> lock(m->mu);
        if (!m->over_limit.exchange(true)) {
          m->refused_bytes = b;
          m->refused_total = after;
        }
        return false;
      }
      m->RaisePeak(after);
      return true;
    }
    const int64_t after = m->current.fetch_add(b, std::memory_order_relaxed) + b;
    if (b > 0) m->RaisePeak(after);
    return true;
  }

  // For rtcSetSceneProgressMonitorFunction: a build that allocates nothing more still asks the predicate.
  static bool OnProgress(void* ptr, double /*fraction*/) {
    return !static_cast<EmbreeBuildMonitor*>(ptr)->ShouldCancel();
  }

  static void OnError(void* ptr, RTCError code, const char* str) {
    auto* m = static_cast<EmbreeBuildMonitor*>(ptr);
    std::lock_guard<std::mutex> lock(m->mu);
    if (m->error != RTC_ERROR_NONE) return;  // the first error is the cause; later ones follow from it
    m->error = code;
    m->error_message = str != nullptr ? str : "";
  }

  // "" or the build's error for what the callbacks saw (cancel first: a cancelled build also fails
  // allocations): cancelled_status, "bvh_memory: ..." or "embree: ...".
  std::string Status(RTCDevice device) {
    if (cancelled.load()) return cancelled_status;
    std::lock_guard<std::mutex> lock(mu);
    if (over_limit.load()) {
      return "bvh_memory: an allocation of " + std::to_string(refused_bytes) +
             " bytes would have brought the scene to " + std::to_string(refused_total) + " bytes, " +
             std::to_string(refused_total - limit) + " bytes over the limit of " + std::to_string(limit) +
             " bytes (" + limit_name + ")";
    }
    RTCError e = error;
    std::string msg = error_message;
    if (e == RTC_ERROR_NONE && device != nullptr) e = rtcGetDeviceError(device);
    if (e == RTC_ERROR_NONE) return "";
    return std::string("embree: ") + EmbreeErrorName(e) + (msg.empty() ? "" : " (" + msg + ")");
  }
};

}  // namespace loomlight::yarn
