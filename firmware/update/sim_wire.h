// Byte-stream helpers for the sim link (a Unix stream socket carrying USB control transfers; the
// frame format is in dfu_protocol.h). Used by the simulated probe's server and the host's sim
// transport, so both sides frame the same way.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "common/core/status.h"
#include "firmware/update/dfu_protocol.h"

namespace d3d::dfu {

// Reads exactly buf.size() bytes. kUnavailable "peer closed" on EOF, kIoError otherwise
// (kUnavailable "timed out" when a socket receive timeout elapses).
Status ReadFull(int fd, std::span<uint8_t> buf);
// Writes all of buf (MSG_NOSIGNAL: a closed peer gives kUnavailable, not SIGPIPE).
Status WriteFull(int fd, std::span<const uint8_t> buf);

// One request frame: kind, SETUP, OUT data.
std::vector<uint8_t> EncodeRequest(uint8_t kind, const SetupPacket& setup,
                                   std::span<const uint8_t> out_data);
// One response frame: result, length, IN data.
std::vector<uint8_t> EncodeResponse(bool stall, std::span<const uint8_t> in_data);

}  // namespace d3d::dfu
