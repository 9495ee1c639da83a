// taxel binary frame: encoder and CRC, shared by the sketch and the host-side check.
// Byte layout (little endian), see docs/serial-protocol.md:
//   0xAA 0x55 | u16 node count N | u32 device seq | u32 device time (us) | N x u16 counts |
//   u16 CRC-16/CCITT-FALSE over every byte after the sync bytes.
// Plain C++ (no Arduino headers) so it compiles on a PC against firmware/test_vectors.txt.
#ifndef TAXEL_FRAME_H
#define TAXEL_FRAME_H

#include <stdint.h>
#include <stddef.h>

static inline uint16_t taxel_crc16_update(uint16_t crc, uint8_t b) {
  crc ^= (uint16_t)b << 8;
  for (uint8_t i = 0; i < 8; i++) {
    crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

static inline uint16_t taxel_crc16(const uint8_t *data, size_t len) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < len; i++) crc = taxel_crc16_update(crc, data[i]);
  return crc;
}

static inline size_t taxel_put16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)(v & 0xFF);
  p[1] = (uint8_t)(v >> 8);
  return 2;
}

static inline size_t taxel_put32(uint8_t *p, uint32_t v) {
  for (uint8_t i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
  return 4;
}

// Bytes a frame of n nodes takes.
static inline size_t taxel_frame_len(uint16_t n) { return 12 + 2 * (size_t)n + 2; }

// Writes one frame into out (taxel_frame_len(n) bytes) and returns its length.
static inline size_t taxel_encode(uint8_t *out, uint32_t seq, uint32_t time_us,
                                  const uint16_t *counts, uint16_t n) {
  size_t k = 0;
  out[k++] = 0xAA;
  out[k++] = 0x55;
  k += taxel_put16(out + k, n);
  k += taxel_put32(out + k, seq);
  k += taxel_put32(out + k, time_us);
  for (uint16_t i = 0; i < n; i++) k += taxel_put16(out + k, counts[i]);
  k += taxel_put16(out + k, taxel_crc16(out + 2, k - 2));
  return k;
}

#endif
