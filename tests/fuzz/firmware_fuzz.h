// Fuzz iterations for the firmware update's parsers and its DFU request handler.
//   FuzzFirmwareImageOnce: first byte picks the parser, the rest is its input —
//     0: image header + full verification (fw::VerifyImageBytes)  1: boot-control record
//     2: DFU/USB wire structures (GETSTATUS, firmware info, string descriptors, SETUP).
//     A successful parse is checked for consistency (re-serialised, re-verified).
//   FuzzDfuRequestsOnce: the input is a script of USB control transfers (any SETUP + data), bus
//     resets, clock steps and blocks of a valid signed image, fed to a provisioned update agent on
//     an in-memory flash. After every step the replies are checked (GETSTATUS 6 bytes, IN data ≤
//     wLength, a valid state); at the end the probe is powered on again and must boot a good
//     signed image: no request sequence may leave it unbootable.
// Neither crashes, throws, or aborts for any input unless an invariant above is broken.
#pragma once

#include <cstddef>
#include <cstdint>

namespace d3d {
void FuzzFirmwareImageOnce(const uint8_t* data, size_t size);
// Returns the major version the probe boots at the end (1: old image, 2: the valid image went in).
int FuzzDfuRequestsOnce(const uint8_t* data, size_t size);
}  // namespace d3d
