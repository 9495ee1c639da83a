// Host-side check that the firmware's encoder produces firmware/test_vectors.txt:
//   g++ -std=c++11 -I taxel_readout check_vectors.cpp -o /tmp/check && /tmp/check < test_vectors.txt
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>
#include "taxel_frame.h"

int main() {
  char line[4096];
  int ok = 0, bad = 0;
  if (taxel_crc16((const uint8_t *)"123456789", 9) != 0x29B1) { std::puts("crc check value wrong"); return 1; }
  while (std::fgets(line, sizeof line, stdin)) {
    if (std::strncmp(line, "frame ", 6) != 0) continue;
    unsigned long seq, t;
    char counts_text[2048], hex[4096];
    if (std::sscanf(line, "frame %lu %lu %2047s %4095s", &seq, &t, counts_text, hex) != 4) return 2;
    std::vector<uint16_t> counts;
    for (char *tok = std::strtok(counts_text, ","); tok; tok = std::strtok(nullptr, ","))
      counts.push_back((uint16_t)std::atoi(tok));
    std::vector<uint8_t> out(taxel_frame_len(counts.size()));
    size_t n = taxel_encode(out.data(), (uint32_t)seq, (uint32_t)t, counts.data(), counts.size());
    std::string got;
    char b[3];
    for (size_t i = 0; i < n; i++) { std::snprintf(b, sizeof b, "%02x", out[i]); got += b; }
    if (got == hex) ok++; else { bad++; std::printf("mismatch for seq %lu\n%s\n%s\n", seq, got.c_str(), hex); }
  }
  std::printf("%d vectors match, %d differ\n", ok, bad);
  return bad ? 1 : 0;
}
