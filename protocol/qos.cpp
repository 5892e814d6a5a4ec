#include "protocol/protocol.h"

namespace d3d::proto {

dds_qos_t* MakeQos(QosProfile profile, int depth) {
  dds_qos_t* q = dds_create_qos();
  auto last = [&](int32_t d) { return depth > 0 ? depth : d; };
  switch (profile) {
    case QosProfile::kBurstWriter:
      // RELIABLE so that reliable readers (recorder) can get every burst by retransmission;
      // best-effort readers still match a reliable writer. KEEP_LAST 16 (~0.5 s at 30 Hz) bounds
      // the probe's memory: a reader more than 16 bursts behind loses the oldest instead of
      // stalling the capture loop forever. max_blocking_time 50 ms: a write that finds the WHC
      // above WhcHigh waits at most this long (counted as a publish failure), less than two burst
      // periods at 30 Hz. VOLATILE: an old burst is of no use to a host that joins later.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_MSECS(50));
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, last(16));
      dds_qset_durability(q, DDS_DURABILITY_VOLATILE);
      break;
    case QosProfile::kBurstReplayWriter:
      // Replaying a file has no camera to keep up with: KEEP_ALL + RELIABLE makes dds_write wait
      // (flow control through WhcHigh) until reliable readers acknowledged, so "as fast as readers
      // take it" loses nothing. max_blocking_time 10 s: a reader that stalls that long fails the
      // write.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(10));
      dds_qset_history(q, DDS_HISTORY_KEEP_ALL, 0);
      dds_qset_durability(q, DDS_DURABILITY_VOLATILE);
      break;
    case QosProfile::kBurstPreviewReader:
      // Live preview wants the freshest burst: BEST_EFFORT (never slows the writer, no repair of a
      // lost burst that is stale anyway) and KEEP_LAST 1 (an unread older burst is replaced).
      dds_qset_reliability(q, DDS_RELIABILITY_BEST_EFFORT, 0);
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, last(1));
      break;
    case QosProfile::kBurstRecordReader:
      // Recording wants every burst: RELIABLE + KEEP_ALL, so nothing is overwritten in the reader
      // cache; the receiver takes samples at once (listener), so the cache stays small.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(q, DDS_HISTORY_KEEP_ALL, 0);
      break;
    case QosProfile::kInfoWriter:
    case QosProfile::kInfoReader:
      // ProbeInfo is state, not a stream: TRANSIENT_LOCAL + KEEP_LAST 1 latches the latest sample
      // in the writer, so a host that joins late receives it (with the calibration) on discovery.
      // RELIABLE: the calibration must arrive. Reader and writer must both say TRANSIENT_LOCAL.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_durability(q, DDS_DURABILITY_TRANSIENT_LOCAL);
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, 1);
      break;
    case QosProfile::kStatusWriter:
      // 1 Hz health reports: RELIABLE so the recorder logs each one; KEEP_LAST 8 (8 s) is ample.
      // TRANSIENT_LOCAL KEEP_LAST 1 would also work, but a joining host gets the next one within 1
      // s.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, last(8));
      break;
    case QosProfile::kStatusReader:
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, last(32));
      break;
    case QosProfile::kCommandWriter:
    case QosProfile::kCommandReader:
      // Commands and acks must neither be lost nor replaced by a later one before they are handled:
      // RELIABLE, KEEP_LAST 32 per instance (far more than a host sends before the ack). VOLATILE:
      // a command sent before the probe came up is not executed later by surprise.
      dds_qset_reliability(q, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(q, DDS_HISTORY_KEEP_LAST, last(32));
      break;
  }
  return q;
}

}  // namespace d3d::proto
