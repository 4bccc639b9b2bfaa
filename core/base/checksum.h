// CRC-32C (Castagnoli polynomial 0x1EDC6F41, reflected 0x82F63B78), the checksum of iSCSI
// (RFC 3720, appendix B.4) and SCTP (RFC 4960). Chosen over a non-cryptographic hash such as
// xxHash because a CRC gives guarantees a packet check wants: every single-bit error, every
// odd number of bit errors and every burst of up to 32 bits is detected (Castagnoli, Braeuer
// and Herrmann 1993), and it needs no extra package. x86-64 CPUs with SSE4.2 compute it in
// hardware; elsewhere a slice-by-8 table (Kounavis and Berry 2005) is used. Both give the
// same result (tested).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

namespace dhr {

// CRC-32C of `data`. To checksum data in pieces, pass the previous result as `crc`:
// crc32c(b, crc32c(a)) == crc32c(a followed by b). Check value: crc32c("123456789") = 0xE3069283.
uint32_t crc32c(std::span<const uint8_t> data, uint32_t crc = 0);

// The portable table-driven implementation (exposed so that tests can compare it with the
// hardware path, which crc32c() uses when the CPU has one).
uint32_t crc32c_portable(std::span<const uint8_t> data, uint32_t crc = 0);

// True when crc32c() uses the CPU's CRC32 instruction.
bool crc32c_hardware();

}  // namespace dhr
