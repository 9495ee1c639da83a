// taxel readout board: scans the paper's 4 x 4 Velostat array and streams frames over USB serial.
//
// Circuit (Zhong et al. 2025; docs/serial-protocol.md): each row line goes through an SPDT switch
// to 0 V (selected) or Vref (all other rows); each column line feeds a non-inverting amplifier
// (Vout = (1 + Rg/R) Vref, Rg = 5.6 kOhm); a 16:1 analog mux (74HC4067 class) routes the column
// amplifiers to one 10-bit ADC input.
//
// Scan order: row-major. Node k = row * 4 + col is the k-th sample of the frame: for each row
// (0..3) the row is selected, ROW_SETTLE_US later the columns 0..3 are read in turn, each
// MUX_SETTLE_US after switching the mux. This matches taxel's node numbering (n0 .. n15).
//
// Output: the binary frame of taxel_frame.h (default), or one ASCII line per frame
// ("<time_us>,<n0>,...,<n15>") when TAXEL_ASCII is defined. Frame rate: FRAME_PERIOD_US, if the
// link keeps up: a binary frame is 46 bytes (460 bits on the wire), so 115200 baud carries at
// most ~250 frames/s and 1 000 000 baud ~2 170 frames/s; ASCII lines are about 70 bytes.
// Pass the same baud to `taxel publisher serial --baud`.

#include "taxel_frame.h"

// ---- Pins: the only place to change for another board -----------------------------------
static const uint8_t ROW_PINS[4] = {2, 3, 4, 5};     // SPDT switch controls, LOW = row selected (0 V)
static const uint8_t MUX_PINS[4] = {6, 7, 8, 9};     // 74HC4067 S0..S3
static const uint8_t MUX_CHANNEL_OF_COL[4] = {0, 1, 2, 3};  // mux input wired to each column amp
static const uint8_t ADC_PIN = A0;
// -------------------------------------------------------------------------------------------

// #define TAXEL_ASCII            // uncomment for ASCII lines instead of binary frames
#define BAUD 115200UL             // 1000000UL for ~1 kHz binary frames
#define FRAME_PERIOD_US 5000UL    // 200 Hz; 1000UL with BAUD 1000000UL
#define ROW_SETTLE_US 50          // after switching rows (switch + thread RC)
#define MUX_SETTLE_US 10          // after switching the mux

static const uint8_t ROWS = 4;
static const uint8_t COLS = 4;
static const uint16_t NODES = ROWS * COLS;

static uint16_t counts[NODES];
static uint8_t frame[12 + 2 * NODES + 2];
static uint32_t seq = 0;
static uint32_t next_frame_us = 0;

static void select_row(uint8_t row) {
  for (uint8_t r = 0; r < ROWS; r++) digitalWrite(ROW_PINS[r], r == row ? LOW : HIGH);
}

static void select_mux(uint8_t channel) {
  for (uint8_t b = 0; b < 4; b++) digitalWrite(MUX_PINS[b], (channel >> b) & 1 ? HIGH : LOW);
}

static void scan() {
  for (uint8_t r = 0; r < ROWS; r++) {
    select_row(r);
    delayMicroseconds(ROW_SETTLE_US);
    for (uint8_t c = 0; c < COLS; c++) {
      select_mux(MUX_CHANNEL_OF_COL[c]);
      delayMicroseconds(MUX_SETTLE_US);
      counts[r * COLS + c] = (uint16_t)analogRead(ADC_PIN);
    }
  }
  select_row(0xFF);  // all rows back to Vref between frames
}

void setup() {
  for (uint8_t i = 0; i < 4; i++) {
    pinMode(ROW_PINS[i], OUTPUT);
    pinMode(MUX_PINS[i], OUTPUT);
  }
  select_row(0xFF);
#if defined(ADCSRA)
  // ADC clock 1 MHz (prescaler 16): ~13 us per conversion instead of ~112 us; 10-bit results
  // stay usable for the slowly varying column voltages.
  ADCSRA = (ADCSRA & 0xF8) | 0x04;
#endif
  Serial.begin(BAUD);
  next_frame_us = micros();
}

void loop() {
  uint32_t now = micros();
  if ((int32_t)(now - next_frame_us) < 0) return;
  next_frame_us += FRAME_PERIOD_US;
  uint32_t t = micros();  // device time of the frame: the start of its scan
  scan();
#ifdef TAXEL_ASCII
  Serial.print((unsigned long)t);
  for (uint16_t k = 0; k < NODES; k++) {
    Serial.print(',');
    Serial.print((unsigned int)counts[k]);
  }
  Serial.print("\r\n");
#else
  size_t len = taxel_encode(frame, seq, t, counts, NODES);
  Serial.write(frame, len);
#endif
  seq++;
}
