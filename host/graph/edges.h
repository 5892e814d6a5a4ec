// Bounded, preallocated edges between the stages of the host's stage graph (stage_graph.h), and
// the triple buffer that hands preview snapshots to the render thread.
//
// Every edge carries pointers to items of a pool the graph preallocates: an edge never allocates
// after construction and never copies an item. Each edge has exactly one producer thread and one
// consumer thread (SPSC).
//
//  LatestEdge   (policy "live": latest wins). One slot, exchanged atomically: the producer swaps
//               its item in and, if the consumer had not taken the previous one yet, gets that
//               older item back: it is dropped (counted) and returned to the pool by the producer.
//               So the consumer always takes the newest item, the oldest is the one dropped, and
//               the producer never waits (wait-free push; the consumer sleeps on a futex,
//               std::atomic::wait, when the slot is empty). AwaitTaken() lets a producer that is
//               itself a stage wait until the consumer has taken its previous item (the graph's
//               demand-driven live mode, stage_graph.h).
//  LosslessEdge (policy "lossless"): a bounded blocking SPSC ring (moodycamel
//               BlockingReaderWriterCircularBuffer, Debian libreaderwriterqueue-dev): the producer
//               blocks while it is full, nothing is dropped, order is kept.
//  TripleBuffer a wait-free single-writer / single-reader "latest value" of a preallocated T (three
//               copies): the writer fills its back copy and publishes it; the reader takes the
//               newest published copy. Neither side ever waits (the render thread reads it).
//
// Closing: the producer calls Close() after its last Push(); Pop() then returns the items still in
// the edge and afterwards false. Close() also wakes a waiting consumer.
#pragma once

#include <readerwriterqueue/readerwritercircularbuffer.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>

namespace d3d {

// Steady clock (ns): the edges' take times and the graph's just-in-time start.
inline int64_t SteadyNowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

enum class EdgePolicy { kLive, kLossless };
const char* EdgePolicyName(EdgePolicy p);  // "live", "lossless"

template <class T>
class Edge {
 public:
  virtual ~Edge() = default;
  // Producer thread. Returns the item that had to be dropped to make room (live), else nullptr.
  virtual T* Push(T* item) = 0;
  // Consumer thread: the next item (blocks while the edge is empty and open); false once the edge
  // is closed and empty.
  virtual bool Pop(T** item) = 0;
  virtual void Close() = 0;  // producer thread, after its last Push
  // Producer thread: returns once the consumer has taken every item pushed so far (live: the slot
  // is empty); lossless edges return at once (their Push waits for room instead).
  virtual void AwaitTaken() {}
  // Any thread: items dropped by Push so far.
  uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }
  // Any thread: when the consumer last took an item (steady clock, ns; 0: never). Live edges only
  // (the graph's just-in-time start); lossless edges return 0.
  virtual int64_t last_taken_ns() const { return 0; }

 protected:
  std::atomic<uint64_t> dropped_{0};
};

template <class T>
class LatestEdge final : public Edge<T> {
 public:
  T* Push(T* item) override {
    T* old = slot_.exchange(item, std::memory_order_acq_rel);
    if (old != nullptr) this->dropped_.fetch_add(1, std::memory_order_relaxed);
    version_.fetch_add(1, std::memory_order_release);
    version_.notify_one();
    return old;
  }
  bool Pop(T** item) override {
    for (;;) {
      const uint32_t v = version_.load(std::memory_order_acquire);
      if (T* got = slot_.exchange(nullptr, std::memory_order_acq_rel); got != nullptr) {
        *item = got;
        Taken();
        return true;
      }
      if (closed_.load(std::memory_order_acquire)) {
        // Close() follows the last Push(): one more look catches an item pushed just before it.
        T* got = slot_.exchange(nullptr, std::memory_order_acq_rel);
        if (got == nullptr) return false;
        *item = got;
        Taken();
        return true;
      }
      version_.wait(v, std::memory_order_acquire);
    }
  }
  void AwaitTaken() override {
    for (;;) {
      const uint32_t v = taken_.load(std::memory_order_acquire);
      if (slot_.load(std::memory_order_acquire) == nullptr) return;
      taken_.wait(v, std::memory_order_acquire);
    }
  }
  void Close() override {
    closed_.store(true, std::memory_order_release);
    version_.fetch_add(1, std::memory_order_release);
    version_.notify_one();
  }
  int64_t last_taken_ns() const override { return taken_ns_.load(std::memory_order_acquire); }

 private:
  void Taken() {
    taken_ns_.store(SteadyNowNs(), std::memory_order_release);
    taken_.fetch_add(1, std::memory_order_release);
    taken_.notify_one();
  }
  std::atomic<T*> slot_{nullptr};
  std::atomic<uint32_t> version_{0};
  std::atomic<uint32_t> taken_{0};    // bumped by the consumer after each take (AwaitTaken)
  std::atomic<int64_t> taken_ns_{0};  // steady clock of the last take (last_taken_ns)
  std::atomic<bool> closed_{false};
};

template <class T>
class LosslessEdge final : public Edge<T> {
 public:
  explicit LosslessEdge(size_t capacity) : ring_(capacity) {}
  T* Push(T* item) override {
    ring_.wait_enqueue(item);
    return nullptr;
  }
  bool Pop(T** item) override {
    for (;;) {
      if (ring_.wait_dequeue_timed(*item, std::int64_t{20000}))
        return true;  // 20 ms: re-check closed
      if (closed_.load(std::memory_order_acquire)) return ring_.try_dequeue(*item);
    }
  }
  void Close() override { closed_.store(true, std::memory_order_release); }

 private:
  moodycamel::BlockingReaderWriterCircularBuffer<T*> ring_;
  std::atomic<bool> closed_{false};
};

template <class T>
std::unique_ptr<Edge<T>> MakeEdge(EdgePolicy policy, size_t lossless_capacity) {
  if (policy == EdgePolicy::kLive) return std::make_unique<LatestEdge<T>>();
  return std::make_unique<LosslessEdge<T>>(lossless_capacity);
}

// Wait-free triple buffer. Writer: Back() → fill → Publish(). Reader: Latest() returns the newest
// published copy (or nullptr before the first Publish); it stays valid and unchanged until the
// reader's next Latest() call. The three T are default-constructed once (preallocate them through
// Back() / reader copies as needed).
template <class T>
class TripleBuffer {
 public:
  T& Back() { return buffers_[back_]; }  // writer thread
  void Publish() {                       // writer thread
    const uint8_t prev =
        middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = prev & kIndex;
  }
  const T* Latest() {  // reader thread
    if (middle_.load(std::memory_order_acquire) & kFresh) {
      const uint8_t prev = middle_.exchange(front_, std::memory_order_acq_rel);
      front_ = prev & kIndex;
      have_ = true;
    }
    return have_ ? &buffers_[front_] : nullptr;
  }

 private:
  static constexpr uint8_t kFresh = 4, kIndex = 3;
  T buffers_[3];
  uint8_t back_ = 0;   // writer's
  uint8_t front_ = 1;  // reader's
  bool have_ = false;  // reader's
  std::atomic<uint8_t> middle_{2};
};

}  // namespace d3d
