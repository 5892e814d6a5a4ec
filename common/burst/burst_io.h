// Bursts on disk: one folder per burst, readable by people (PNG) and by numpy (.npy truth maps).
//
//   BURST_DIR/burst.json            {"format": "d3dscan.burst", "version": 1, "sequence": N,
//                                     "frames": [{"file", "pattern", "timestamp_ns",
//                                                 "world_from_probe": [tx,ty,tz,qx,qy,qz,qw]?}],
//                                     "truth_frames": [indices of frames with truth maps]}
//   BURST_DIR/frame_K.png           8- or 16-bit grey
//   BURST_DIR/truth_K/depth_mm.npy, points_in_cam.npy, projector_uv.npy, face_index.npy,
//                     visibility.png, label.png        (only for frames listed in truth_frames)
//   BURST_DIR/truth_ref/ ...        the same at the reference time (burst.json "reference":
//                                   {"timestamp_ns", "world_from_probe"}), when the burst has it
// Poses are written with the truth (simulation); a real capture has none.
#pragma once

#include <string>
#include <vector>

#include "common/burst/burst.h"
#include "common/core/status.h"

namespace d3d {

// Writes `burst` into `dir` (created). Truth maps are written for the frames in `truth_frames`
// that have them. IO_ERROR on failure; INVALID_ARGUMENT for an empty burst.
[[nodiscard]] Status WriteBurstDir(const std::string& dir, const Burst& burst,
                                   const std::vector<int>& truth_frames);

// Reads a burst folder. With read_truth, loads poses and truth maps where present. Errors:
// NOT_FOUND (no burst.json / a frame file missing), PARSE_ERROR (malformed json, unreadable image),
// UNSUPPORTED (newer version), INVALID_ARGUMENT (frames of different sizes or types).
[[nodiscard]] Status ReadBurstDir(const std::string& dir, bool read_truth, Burst* out);

}  // namespace d3d
