// d3d-bench-dds: throughput and latency of PhaseBurst over DDS between two processes on one machine
// (loopback, the shipped Cyclone config unless $CYCLONEDDS_URI is set).
//
// For each burst size (4 frames of 640×480 and of 1280×1024, 8 bit) and each offered rate, a child
// process subscribes like the recorder (host/receiver, RELIABLE KEEP_ALL, the listener copies each
// sample out) and the parent publishes N bursts with the probe's writer QoS, frame 0 stamped with
// the write time. Latency = the subscriber's take time − that stamp (same clock). A rate is
// lossless when all N arrive with no sequence gap. "max" publishes with the replay writer
// (KEEP_ALL, flow controlled) as fast as the reader takes it. Prints one line per trial and a
// summary per size.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <random>
#include <thread>

#include "common/options/option_registry.h"
#include "host/receiver/receiver.h"
#include "protocol/protocol.h"
#include "tools/dds/tool_dds.h"

using namespace d3d;

namespace {

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

struct TrialResult {
  int64_t received = 0;
  uint64_t gaps = 0, dropped = 0;
  double p50_ms = 0, p99_ms = 0, max_ms = 0;
  double achieved_hz = 0;
};

// Child: receive up to n bursts (stop 3 s after the last one or 60 s overall), write the result.
int Subscriber(int domain, int64_t n, int out_fd) {
  proto::DdsParticipant pp;
  if (!tools::CreateToolParticipant(domain, &pp, "d3d-bench-dds").ok()) return 1;
  ReceiverOptions o;
  o.queue_capacity = 64;
  BurstReceiver rx(o);
  if (!rx.Start(&pp).ok()) return 1;
  std::vector<double> lat_ms;
  int64_t first = 0, last = 0;
  const int64_t deadline = NowNs() + 60'000'000'000;
  int64_t last_rx = 0;
  while (static_cast<int64_t>(lat_ms.size()) < n && NowNs() < deadline) {
    ReceivedSample r;
    if (!rx.Pop(&r, 100'000'000)) {
      if (last_rx > 0 && NowNs() - last_rx > 3'000'000'000) break;
      continue;
    }
    if (const auto* b = std::get_if<proto::BurstMsg>(&r.msg)) {
      lat_ms.push_back(static_cast<double>(r.receive_ns - b->frames[0].timestamp_ns) * 1e-6);
      if (first == 0) first = r.receive_ns;
      last = r.receive_ns;
      last_rx = NowNs();
    }
    rx.Recycle(std::move(r));
  }
  TrialResult t;
  t.received = static_cast<int64_t>(lat_ms.size());
  const ReceiverCounters c = rx.counters();
  t.gaps = c.bursts_missing;
  t.dropped = c.dropped_total();
  if (!lat_ms.empty()) {
    std::sort(lat_ms.begin(), lat_ms.end());
    t.p50_ms = lat_ms[lat_ms.size() / 2];
    t.p99_ms = lat_ms[std::min(lat_ms.size() - 1,
                               static_cast<size_t>(0.99 * static_cast<double>(lat_ms.size())))];
    t.max_ms = lat_ms.back();
    if (last > first)
      t.achieved_hz =
          static_cast<double>(lat_ms.size() - 1) / (static_cast<double>(last - first) * 1e-9);
  }
  return write(out_fd, &t, sizeof t) == sizeof t ? 0 : 1;
}

// Parent: publish n bursts of w×h at rate_hz (0 = max), return the child's result.
bool Trial(int domain, int w, int h, double rate_hz, int64_t n, TrialResult* result) {
  int fds[2];
  if (pipe(fds) != 0) return false;
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    _exit(Subscriber(domain, n, fds[1]));
  }
  close(fds[1]);
  bool ok = true;
  {
    proto::DdsParticipant pp;
    ok = tools::CreateToolParticipant(domain, &pp, "d3d-bench-dds").ok();
    Status st;
    const dds_entity_t topic =
        ok ? pp.Topic(&d3d_proto_PhaseBurst_desc, proto::kTopicPhaseBurst, &st) : 0;
    std::unique_ptr<dds_qos_t, proto::QosDeleter> q(proto::MakeQos(
        rate_hz > 0 ? proto::QosProfile::kBurstWriter : proto::QosProfile::kBurstReplayWriter));
    const dds_entity_t wr = ok ? dds_create_writer(pp.participant(), topic, q.get(), nullptr) : -1;
    ok = ok && wr > 0 && tools::WaitForReaders(wr, 1, 30, nullptr);
    // Let the subscriber's other readers (ProbeInfo/Status) finish discovery too.
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    proto::BurstMsg b;
    b.serial = "BENCH";
    b.protocol_version = proto::kProtocolVersion;
    b.width = static_cast<uint32_t>(w);
    b.height = static_cast<uint32_t>(h);
    b.pattern_set = "phase4-marker";
    std::mt19937 rng(7);
    for (int f = 0; f < 4; ++f) {
      proto::FrameMsg fr;
      fr.pattern_index = static_cast<uint16_t>(f);
      fr.pixels.resize(static_cast<size_t>(w) * h);
      for (auto& p : fr.pixels) p = static_cast<uint8_t>(rng());
      b.frames.push_back(std::move(fr));
    }
    std::vector<d3d_proto_ImageFrame> storage;
    const auto start = std::chrono::steady_clock::now();
    for (int64_t i = 0; ok && i < n; ++i) {
      if (rate_hz > 0)
        std::this_thread::sleep_until(start + std::chrono::nanoseconds(static_cast<int64_t>(
                                                  static_cast<double>(i) * 1e9 / rate_hz)));
      b.burst_seq = static_cast<uint64_t>(i);
      const int64_t t = NowNs();
      for (int f = 0; f < 4; ++f) b.frames[f].timestamp_ns = t + f;
      d3d_proto_PhaseBurst s;
      proto::ToDds(b, &s, &storage);
      (void)dds_write(wr, &s);  // a timeout shows up as a loss at the subscriber
    }
    if (ok) (void)dds_wait_for_acks(wr, DDS_SECS(10));
  }
  ok = read(fds[0], result, sizeof *result) == sizeof *result && ok;
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return ok && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  OptionRegistry options(
      "d3d-bench-dds: max lossless PhaseBurst throughput and p50/p99 latency over loopback (two "
      "processes)");
  int domain = 90;
  double seconds = 2.0;
  std::vector<double> rates = {30, 60, 90, 120, 180, 240};
  options.Add("--domain", &domain, "DDS domain id");
  options.Add("--seconds", &seconds, "duration of each fixed-rate trial");
  options.Add("--rates", &rates, "offered burst rates (Hz); a 'max' trial always follows");
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  std::printf("%-10s %8s %8s %8s %6s %9s %9s %9s %10s %9s\n", "size", "offered", "sent", "recv",
              "lost", "p50_ms", "p99_ms", "max_ms", "recv_hz", "MB/s");
  for (const auto& [w, h] : std::vector<std::pair<int, int>>{{640, 480}, {1280, 1024}}) {
    double best_lossless = 0;
    TrialResult at60{};
    for (double r : rates) {
      const int64_t n = std::max<int64_t>(60, static_cast<int64_t>(r * seconds));
      TrialResult t;
      if (!Trial(domain, w, h, r, n, &t)) {
        std::printf("%dx%d @ %.0f: trial failed\n", w, h, r);
        continue;
      }
      const int64_t lost = n - t.received;
      std::printf("%4dx%-5d %8.0f %8lld %8lld %6lld %9.2f %9.2f %9.2f %10.1f %9.1f\n", w, h, r,
                  static_cast<long long>(n), static_cast<long long>(t.received),
                  static_cast<long long>(lost), t.p50_ms, t.p99_ms, t.max_ms, t.achieved_hz,
                  t.achieved_hz * 4.0 * w * h / 1e6);
      std::fflush(stdout);
      if (lost == 0 && t.gaps == 0) best_lossless = std::max(best_lossless, r);
      if (r == 60) at60 = t;
    }
    TrialResult t;
    const int64_t n = 300;
    if (Trial(domain, w, h, 0, n, &t)) {
      std::printf("%4dx%-5d %8s %8lld %8lld %6lld %9.2f %9.2f %9.2f %10.1f %9.1f\n", w, h, "max",
                  static_cast<long long>(n), static_cast<long long>(t.received),
                  static_cast<long long>(n - t.received), t.p50_ms, t.p99_ms, t.max_ms,
                  t.achieved_hz, t.achieved_hz * 4.0 * w * h / 1e6);
    }
    std::printf(
        "SUMMARY %dx%d: max lossless offered rate %.0f bursts/s; at 60 Hz p50 %.2f ms p99 %.2f ms; "
        "flow-controlled max %.1f bursts/s (%lld/%lld)\n",
        w, h, best_lossless, at60.p50_ms, at60.p99_ms, t.achieved_hz,
        static_cast<long long>(t.received), static_cast<long long>(n));
    std::fflush(stdout);
  }
  return 0;
}
