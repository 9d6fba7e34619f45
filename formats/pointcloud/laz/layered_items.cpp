// Item codecs of the layered (LAS 1.4) LAZ compressor; see layered_items.h for the design.
#include "formats/pointcloud/laz/layered_items.h"

#include <bit>
#include <cstring>

#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz::layered {

static_assert(std::endian::native == std::endian::little,
              "the layered LAZ codec assumes a little-endian host");

namespace {

template <typename T>
T loadLE(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <typename T>
void storeLE(std::uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

void appendU32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}

// Closes a layer and appends its size and (if its values changed in the chunk) its bytes.  A layer whose
// values never changed is dropped: the decoder repeats the first point's value for it.
void finishLayer(OutLayer& layer, std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes) {
  layer.enc->done();
  layer.enc.reset();
  if (layer.changed) {
    if (layer.bytes.size() > 0xFFFFFFFFu) throw LazError("layer of a layered chunk exceeds 4 GiB");
    appendU32(sizes, static_cast<std::uint32_t>(layer.bytes.size()));
    bytes.insert(bytes.end(), layer.bytes.begin(), layer.bytes.end());
  } else {
    appendU32(sizes, 0);
  }
}

void startLayer(InLayer& layer, const std::uint8_t* data, std::uint32_t size, bool requested) {
  layer.active = requested && size > 0;
  layer.size = size;
  if (layer.active) layer.dec.init(data, data + size);
}

// 32-bit wrap-around helpers (the reference coder's int arithmetic, without signed overflow).
inline std::int32_t wrapAdd(std::int32_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) + static_cast<std::uint32_t>(b));
}
inline std::int32_t wrapSub(std::int32_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(a) - static_cast<std::uint32_t>(b));
}
inline std::int32_t wrapMul(std::int32_t a, std::int32_t b) {
  return static_cast<std::int32_t>(static_cast<std::uint32_t>(static_cast<std::int64_t>(a) * b));
}

// Byte arithmetic of the RGB / NIR / extra-byte layers: sums wrap modulo 256 ("fold"), predictions
// saturate ("clamp").
inline std::uint32_t fold8(std::int32_t v) {
  return static_cast<std::uint32_t>(v) & 0xFFu;
}
inline std::int32_t clamp8(std::int32_t v) {
  return v < 0 ? 0 : (v > 255 ? 255 : v);
}

// Decodes one byte as prediction + coded correction (mod 256).
inline std::int32_t decodeByte(ArithmeticDecoder& d, ArithmeticModel& m, std::int32_t prediction) {
  return static_cast<std::int32_t>(fold8(static_cast<std::int32_t>(d.decodeSymbol(m)) + prediction));
}

// Context selectors of the Point14 XY / Z layers, indexed [numberOfReturns][returnNumber].  The "return
// map" folds the 256 (n, r) combinations into six classes of similar point spacing; the table values
// are part of the format.
constexpr std::uint8_t kReturnMap6[16][16] = {
    {0, 1, 2, 3, 4, 5, 3, 4, 4, 5, 5, 5, 5, 5, 5, 5}, {1, 0, 1, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3},
    {2, 1, 2, 4, 4, 4, 4, 4, 4, 4, 4, 3, 3, 3, 3, 3}, {3, 3, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4},
    {3, 3, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4, 4}, {4, 3, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4, 4},
    {4, 3, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4, 4}, {5, 3, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4, 4},
    {5, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 4, 4, 4, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 4, 4, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4, 4}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5, 4},
    {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5, 5}, {5, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 5}};

// The "return level" (how deep in the pulse the point is): |n - r| capped at 7; selects the Z predictor.
inline std::uint32_t returnLevel(std::uint32_t n, std::uint32_t r) {
  const std::uint32_t d = n > r ? n - r : r - n;
  return d < 7 ? d : 7;
}

// First/last-of-pulse class of a point: bit 1 = first return, bit 0 = last return.
inline std::uint32_t pulseClass(std::uint32_t n, std::uint32_t r) {
  return (r == 1 ? 2u : 0u) + (r >= n ? 1u : 0u);
}

// Context of the Y corrector and the Z corrector: the (even-rounded) k of the previous corrector(s).
inline std::uint32_t kContext(std::uint32_t k, std::uint32_t cap) {
  return k < cap ? (k & ~1u) : cap;
}

// GPS time multiplier alphabet: 0 = "unrelated jump", 1..499 = multiples of the last difference,
// 500 = "500 or more", 501..510 = -1..-10, 511 = a new 64-bit sequence start, 512..514 = switch to one of
// the other three remembered sequences.
constexpr std::int32_t kGpsMulti = 500;
constexpr std::int32_t kGpsMultiMinus = -10;
constexpr std::uint32_t kGpsCodeFull = kGpsMulti - kGpsMultiMinus + 1;    // 511
constexpr std::uint32_t kGpsMultiTotal = kGpsMulti - kGpsMultiMinus + 5;  // 515 symbols

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Point14Fields
// ---------------------------------------------------------------------------------------------------------
void Point14Fields::load(const std::uint8_t* rec) {
  x = loadLE<std::int32_t>(rec);
  y = loadLE<std::int32_t>(rec + 4);
  z = loadLE<std::int32_t>(rec + 8);
  intensity = loadLE<std::uint16_t>(rec + 12);
  returnNumber = rec[14] & 0x0F;
  numberOfReturns = rec[14] >> 4;
  const std::uint8_t b = rec[15];
  channel = (b >> 4) & 0x03;
  flags = static_cast<std::uint8_t>((b & 0x0F) | ((b >> 2) & 0x30));  // dir (bit 6) -> 4, edge (bit 7) -> 5
  classification = rec[16];
  userData = rec[17];
  scanAngle = loadLE<std::int16_t>(rec + 18);
  pointSource = loadLE<std::uint16_t>(rec + 20);
  gpsBits = loadLE<std::uint64_t>(rec + 22);
}

void Point14Fields::store(std::uint8_t* rec) const {
  storeLE(rec, x);
  storeLE(rec + 4, y);
  storeLE(rec + 8, z);
  storeLE(rec + 12, intensity);
  rec[14] = static_cast<std::uint8_t>(returnNumber | (numberOfReturns << 4));
  rec[15] = static_cast<std::uint8_t>((flags & 0x0F) | (channel << 4) | ((flags & 0x30) << 2));
  rec[16] = classification;
  rec[17] = userData;
  storeLE(rec + 18, scanAngle);
  storeLE(rec + 20, pointSource);
  storeLE(rec + 22, gpsBits);
}

// ---------------------------------------------------------------------------------------------------------
// Point14Codec
// ---------------------------------------------------------------------------------------------------------
struct Point14Codec::Context {
  Point14Fields last;

  // XY layer: "what changed" symbol per last-point class, scanner channel step, return counts, X/Y.
  std::vector<ArithmeticModel> changedValues = std::vector<ArithmeticModel>(8, ArithmeticModel(128));
  ArithmeticModel scannerChannel{3};
  ArithmeticModel returnNumberGpsSame{13};
  std::array<std::unique_ptr<ArithmeticModel>, 16> numberOfReturns, returnNumber;
  IntegerCompressor icDx{32, 2}, icDy{32, 22};
  std::array<Median5, 12> lastDx, lastDy;

  // Z layer: one predictor per return level.
  IntegerCompressor icZ{32, 20};
  std::array<std::int32_t, 8> lastZ{};

  // Classification / flags / user data: one model per previous value (class: per 5-bit class and
  // single-return bit; user data: per value / 4).
  std::array<std::unique_ptr<ArithmeticModel>, 64> classification, flags, userData;

  // Intensity: one predictor per pulse class and GPS-changed bit.
  IntegerCompressor icIntensity{16, 4};
  std::array<std::uint16_t, 8> lastIntensity{};

  IntegerCompressor icScanAngle{16, 2};
  IntegerCompressor icPointSource{16, 1};

  // GPS time: up to four interleaved time sequences, each with its last value and last difference.
  std::uint32_t gpsLast = 0, gpsNext = 0;
  std::array<std::uint64_t, 4> gps{};
  std::array<std::int32_t, 4> gpsDiff{}, gpsExtreme{};
  ArithmeticModel gpsMulti{kGpsMultiTotal}, gpsZeroDiff{5};
  IntegerCompressor icGps{32, 9};
};

Point14Codec::Point14Codec() = default;
Point14Codec::~Point14Codec() = default;

[[gnu::noinline]] void Point14Codec::initContext(std::uint32_t index, const Point14Fields& seed) {
  if (!ctx_[index]) ctx_[index] = std::make_unique<Context>();
  Context& c = *ctx_[index];
  for (auto& m : c.changedValues) m.reset();
  c.scannerChannel.reset();
  c.returnNumberGpsSame.reset();
  for (auto& m : c.numberOfReturns)
    if (m) m->reset();
  for (auto& m : c.returnNumber)
    if (m) m->reset();
  // initDecompressor() and initCompressor() are the same reset (integer_compressor.h), so one context
  // start serves both directions.
  c.icDx.initDecompressor();
  c.icDy.initDecompressor();
  for (auto& m : c.lastDx) m.reset();
  for (auto& m : c.lastDy) m.reset();
  // Models of layers that are skipped in this chunk are left alone: resetting them is most of the cost of
  // a context start, which matters for files with small chunks (COPC).
  if (live(kLZ)) c.icZ.initDecompressor();
  c.lastZ.fill(seed.z);
  for (int i = 0; i < 64; ++i) {
    if (c.classification[i] && live(kLClass)) c.classification[i]->reset();
    if (c.flags[i] && live(kLFlags)) c.flags[i]->reset();
    if (c.userData[i] && live(kLUserData)) c.userData[i]->reset();
  }
  if (live(kLIntensity)) c.icIntensity.initDecompressor();
  c.lastIntensity.fill(seed.intensity);
  if (live(kLScanAngle)) c.icScanAngle.initDecompressor();
  if (live(kLPointSource)) c.icPointSource.initDecompressor();
  if (live(kLGps)) {
    c.gpsMulti.reset();
    c.gpsZeroDiff.reset();
    c.icGps.initDecompressor();
  }
  c.gpsLast = c.gpsNext = 0;
  c.gpsDiff.fill(0);
  c.gpsExtreme.fill(0);
  c.gps = {seed.gpsBits, 0, 0, 0};
  c.last = seed;
  c.last.gpsChanged = false;
  used_[index] = true;
}

void Point14Codec::beginDecode(const std::uint8_t* firstRecord, const std::uint8_t* const* layerData,
                               const std::uint32_t* layerSize, std::uint32_t layers) {
  Point14Fields first;
  first.load(firstRecord);
  encoding_ = false;
  layers |= kXY;  // every other layer needs the returns and the "changed" bits of the XY layer
  for (int i = 0; i < kLayerCount; ++i) startLayer(in_[i], layerData[i], layerSize[i], layers & kLayerBit[i]);
  used_.fill(false);
  cur_ = first.channel;
  initContext(cur_, first);
}

const char* Point14Codec::damagedLayer() const {
  static const char* const kNames[kLayerCount] = {
      "XY/returns", "Z",         "classification", "flags",   "intensity",
      "scan angle", "user data", "point source",   "GPS time"};
  for (int i = 0; i < kLayerCount; ++i)
    if (in_[i].damaged()) return kNames[i];
  return nullptr;
}

const Point14Fields& Point14Codec::current() const {
  return ctx_[cur_]->last;
}

// flatten: inline the coder's symbol and corrector decoding into this per-point hot path.
[[gnu::flatten]] const Point14Fields& Point14Codec::decodeNext() {
  Context* c = ctx_[cur_].get();
  Point14Fields* last = &c->last;
  ArithmeticDecoder& dxy = in_[kLXY].dec;

  // What changed relative to the previous point of this channel, coded in the context of whether that
  // point was a first / last return and whether its GPS time had changed.
  const std::uint32_t lpr = (last->returnNumber == 1 ? 1u : 0u) +
                            (last->returnNumber >= last->numberOfReturns ? 2u : 0u) +
                            (last->gpsChanged ? 4u : 0u);
  const std::uint32_t changed = dxy.decodeSymbol(c->changedValues[lpr]);

  if (changed & (1u << 6)) {  // scanner channel switch: channel = old + step + 1 (mod 4)
    const std::uint32_t step = dxy.decodeSymbol(c->scannerChannel);
    const std::uint32_t next = (cur_ + step + 1) & 3;
    if (!used_[next]) initContext(next, *last);
    cur_ = next;
    c = ctx_[next].get();
    last = &c->last;
    last->channel = static_cast<std::uint8_t>(next);
  }
  const bool gpsChange = changed & (1u << 4);

  const std::uint32_t lastN = last->numberOfReturns;
  const std::uint32_t lastR = last->returnNumber;
  std::uint32_t n = lastN;
  if (changed & (1u << 2)) {
    n = dxy.decodeSymbol(lazyModel(c->numberOfReturns[lastN], 16));
    last->numberOfReturns = static_cast<std::uint8_t>(n);
  }
  std::uint32_t r;
  switch (changed & 3u) {
    case 0:
      r = lastR;
      break;
    case 1:
      r = (lastR + 1) & 15;
      break;
    case 2:
      r = (lastR + 15) & 15;
      break;
    default:
      if (gpsChange) {
        r = dxy.decodeSymbol(lazyModel(c->returnNumber[lastR], 16));
      } else {
        r = (lastR + dxy.decodeSymbol(c->returnNumberGpsSame) + 2) & 15;
      }
      break;
  }
  last->returnNumber = static_cast<std::uint8_t>(r);

  const std::uint32_t m = kReturnMap6[n][r];
  const std::uint32_t cpr = pulseClass(n, r);
  const std::uint32_t single = n == 1 ? 1u : 0u;
  const std::uint32_t xyIdx = (m << 1) | (gpsChange ? 1u : 0u);

  std::int32_t diff = c->icDx.decompress(dxy, c->lastDx[xyIdx].get(), single);
  last->x = wrapAdd(last->x, diff);
  c->lastDx[xyIdx].add(diff);
  diff = c->icDy.decompress(dxy, c->lastDy[xyIdx].get(), single + kContext(c->icDx.k(), 20));
  last->y = wrapAdd(last->y, diff);
  c->lastDy[xyIdx].add(diff);

  if (in_[kLZ].active) {
    const std::uint32_t l = returnLevel(n, r);
    const std::uint32_t kb = (c->icDx.k() + c->icDy.k()) / 2;
    last->z = c->icZ.decompress(in_[kLZ].dec, c->lastZ[l], single + kContext(kb, 18));
    c->lastZ[l] = last->z;
  }
  if (in_[kLClass].active) {
    const std::uint32_t ccc = ((last->classification & 0x1Fu) << 1) + (cpr == 3 ? 1u : 0u);
    last->classification =
        static_cast<std::uint8_t>(in_[kLClass].dec.decodeSymbol(lazyModel(c->classification[ccc], 256)));
  }
  if (in_[kLFlags].active) {
    last->flags =
        static_cast<std::uint8_t>(in_[kLFlags].dec.decodeSymbol(lazyModel(c->flags[last->flags], 64)));
  }
  if (in_[kLIntensity].active) {
    const std::uint32_t idx = (cpr << 1) | (gpsChange ? 1u : 0u);
    const auto v = static_cast<std::uint16_t>(
        c->icIntensity.decompress(in_[kLIntensity].dec, c->lastIntensity[idx], cpr));
    c->lastIntensity[idx] = v;
    last->intensity = v;
  }
  if (in_[kLScanAngle].active && (changed & (1u << 3))) {
    last->scanAngle = static_cast<std::int16_t>(static_cast<std::uint16_t>(
        c->icScanAngle.decompress(in_[kLScanAngle].dec, last->scanAngle, gpsChange ? 1u : 0u)));
  }
  if (in_[kLUserData].active) {
    last->userData = static_cast<std::uint8_t>(
        in_[kLUserData].dec.decodeSymbol(lazyModel(c->userData[last->userData / 4], 256)));
  }
  if (in_[kLPointSource].active && (changed & (1u << 5))) {
    last->pointSource =
        static_cast<std::uint16_t>(c->icPointSource.decompress(in_[kLPointSource].dec, last->pointSource));
  }
  if (in_[kLGps].active && gpsChange) {
    decodeGps(*c);
    last->gpsBits = c->gps[c->gpsLast];
  }
  last->gpsChanged = gpsChange;
  return *last;
}

void Point14Codec::decodeGps(Context& c) {
  ArithmeticDecoder& dec = in_[kLGps].dec;
  // A valid stream switches sequence at most once per point; more means damaged data (and must not loop).
  for (int hops = 0;; ++hops) {
    if (hops > 3) throw LazError("GPS time layer keeps switching time sequences (damaged data)");
    const std::uint32_t L = c.gpsLast;
    std::uint32_t multi;
    bool newSequence = false;
    if (c.gpsDiff[L] == 0) {
      multi = dec.decodeSymbol(c.gpsZeroDiff);
      if (multi == 0) {  // a 32-bit difference
        c.gpsDiff[L] = c.icGps.decompress(dec, 0, 0);
        c.gps[L] += static_cast<std::uint64_t>(static_cast<std::int64_t>(c.gpsDiff[L]));
        c.gpsExtreme[L] = 0;
        return;
      }
      if (multi >= 2) {  // switch to another remembered sequence and code relative to it
        c.gpsLast = (L + multi - 1) & 3;
        continue;
      }
      newSequence = true;
    } else {
      multi = dec.decodeSymbol(c.gpsMulti);
      if (multi == 1) {  // the common case: same spacing as last time
        c.gps[L] +=
            static_cast<std::uint64_t>(static_cast<std::int64_t>(c.icGps.decompress(dec, c.gpsDiff[L], 1)));
        c.gpsExtreme[L] = 0;
        return;
      }
      if (multi < kGpsCodeFull) {
        std::int32_t d;
        bool extreme = false;
        if (multi == 0) {
          d = c.icGps.decompress(dec, 0, 7);
          extreme = true;
        } else if (multi < static_cast<std::uint32_t>(kGpsMulti)) {
          d = c.icGps.decompress(dec, wrapMul(static_cast<std::int32_t>(multi), c.gpsDiff[L]),
                                 multi < 10 ? 2 : 3);
        } else if (multi == static_cast<std::uint32_t>(kGpsMulti)) {
          d = c.icGps.decompress(dec, wrapMul(kGpsMulti, c.gpsDiff[L]), 4);
          extreme = true;
        } else {
          const std::int32_t neg = kGpsMulti - static_cast<std::int32_t>(multi);  // -1 .. -10
          if (neg > kGpsMultiMinus) {
            d = c.icGps.decompress(dec, wrapMul(neg, c.gpsDiff[L]), 5);
          } else {
            d = c.icGps.decompress(dec, wrapMul(kGpsMultiMinus, c.gpsDiff[L]), 6);
            extreme = true;
          }
        }
        if (extreme && ++c.gpsExtreme[L] > 3) {  // persistent new spacing: adopt it
          c.gpsDiff[L] = d;
          c.gpsExtreme[L] = 0;
        }
        c.gps[L] += static_cast<std::uint64_t>(static_cast<std::int64_t>(d));
        return;
      }
      if (multi > kGpsCodeFull) {
        c.gpsLast = (L + multi - kGpsCodeFull) & 3;
        continue;
      }
      newSequence = true;
    }
    if (newSequence) {  // a new sequence: high 32 bits predicted from the current one, low 32 raw
      c.gpsNext = (c.gpsNext + 1) & 3;
      const auto high =
          static_cast<std::uint32_t>(c.icGps.decompress(dec, static_cast<std::int32_t>(c.gps[L] >> 32), 8));
      c.gps[c.gpsNext] = (static_cast<std::uint64_t>(high) << 32) | dec.readInt();
      c.gpsLast = c.gpsNext;
      c.gpsDiff[c.gpsLast] = 0;
      c.gpsExtreme[c.gpsLast] = 0;
      return;
    }
  }
}

void Point14Codec::beginEncode(const std::uint8_t* firstRecord) {
  Point14Fields first;
  first.load(firstRecord);
  encoding_ = true;
  used_.fill(false);
  cur_ = first.channel;
  initContext(cur_, first);
  for (OutLayer& l : out_) l.start();
  out_[kLXY].changed = true;  // XY and Z are always stored
  out_[kLZ].changed = true;
}

void Point14Codec::encodeNext(const std::uint8_t* rec) {
  Point14Fields p;
  p.load(rec);
  Context* const old = ctx_[cur_].get();
  const Point14Fields& oldLast = old->last;
  const std::uint32_t lpr = (oldLast.returnNumber == 1 ? 1u : 0u) +
                            (oldLast.returnNumber >= oldLast.numberOfReturns ? 2u : 0u) +
                            (oldLast.gpsChanged ? 4u : 0u);

  // Changes are measured against the last point of the point's own channel (seeded from the current
  // channel if that channel is new in this chunk), as the decoder will see it after the switch.
  const std::uint32_t ch = p.channel;
  if (ch != cur_ && !used_[ch]) initContext(ch, oldLast);
  Context* const c = ctx_[ch].get();
  Point14Fields* const last = &c->last;

  const bool psChange = p.pointSource != last->pointSource;
  const bool gpsChange = p.gpsBits != last->gpsBits;  // bitwise: keeps -0.0 vs 0.0 and NaN payloads exact
  const bool saChange = p.scanAngle != last->scanAngle;
  const std::uint32_t lastN = last->numberOfReturns, lastR = last->returnNumber;
  const std::uint32_t n = p.numberOfReturns, r = p.returnNumber;

  std::uint32_t changed = ((ch != cur_ ? 1u : 0u) << 6) | ((psChange ? 1u : 0u) << 5) |
                          ((gpsChange ? 1u : 0u) << 4) | ((saChange ? 1u : 0u) << 3) |
                          ((n != lastN ? 1u : 0u) << 2);
  if (r != lastR) {
    if (r == ((lastR + 1) & 15))
      changed |= 1;
    else if (r == ((lastR + 15) & 15))
      changed |= 2;
    else
      changed |= 3;
  }
  ArithmeticEncoder& exy = *out_[kLXY].enc;
  exy.encodeSymbol(old->changedValues[lpr], changed);
  if (ch != cur_) {
    exy.encodeSymbol(old->scannerChannel, (ch - cur_ + 3) & 3);  // channel = old + sym + 1 (mod 4)
    cur_ = ch;
  }
  if (changed & (1u << 2)) exy.encodeSymbol(lazyModel(c->numberOfReturns[lastN], 16), n);
  if ((changed & 3u) == 3u) {
    if (gpsChange) {
      exy.encodeSymbol(lazyModel(c->returnNumber[lastR], 16), r);
    } else {
      exy.encodeSymbol(c->returnNumberGpsSame, (r - lastR - 2) & 15);  // r = last + sym + 2 (mod 16)
    }
  }

  const std::uint32_t m = kReturnMap6[n][r];
  const std::uint32_t cpr = pulseClass(n, r);
  const std::uint32_t single = n == 1 ? 1u : 0u;
  const std::uint32_t xyIdx = (m << 1) | (gpsChange ? 1u : 0u);

  std::int32_t diff = wrapSub(p.x, last->x);
  c->icDx.compress(exy, c->lastDx[xyIdx].get(), diff, single);
  c->lastDx[xyIdx].add(diff);
  diff = wrapSub(p.y, last->y);
  c->icDy.compress(exy, c->lastDy[xyIdx].get(), diff, single + kContext(c->icDx.k(), 20));
  c->lastDy[xyIdx].add(diff);

  {
    const std::uint32_t l = returnLevel(n, r);
    const std::uint32_t kb = (c->icDx.k() + c->icDy.k()) / 2;
    c->icZ.compress(*out_[kLZ].enc, c->lastZ[l], p.z, single + kContext(kb, 18));
    c->lastZ[l] = p.z;
  }
  {
    if (p.classification != last->classification) out_[kLClass].changed = true;
    const std::uint32_t ccc = ((last->classification & 0x1Fu) << 1) + (cpr == 3 ? 1u : 0u);
    out_[kLClass].enc->encodeSymbol(lazyModel(c->classification[ccc], 256), p.classification);
  }
  {
    if (p.flags != last->flags) out_[kLFlags].changed = true;
    out_[kLFlags].enc->encodeSymbol(lazyModel(c->flags[last->flags], 64), p.flags);
  }
  {
    if (p.intensity != last->intensity) out_[kLIntensity].changed = true;
    const std::uint32_t idx = (cpr << 1) | (gpsChange ? 1u : 0u);
    c->icIntensity.compress(*out_[kLIntensity].enc, c->lastIntensity[idx], p.intensity, cpr);
    c->lastIntensity[idx] = p.intensity;
  }
  if (saChange) {
    out_[kLScanAngle].changed = true;
    c->icScanAngle.compress(*out_[kLScanAngle].enc, last->scanAngle, p.scanAngle, gpsChange ? 1u : 0u);
  }
  {
    if (p.userData != last->userData) out_[kLUserData].changed = true;
    out_[kLUserData].enc->encodeSymbol(lazyModel(c->userData[last->userData / 4], 256), p.userData);
  }
  if (psChange) {
    out_[kLPointSource].changed = true;
    c->icPointSource.compress(*out_[kLPointSource].enc, last->pointSource, p.pointSource);
  }
  if (gpsChange) {
    out_[kLGps].changed = true;
    encodeGps(*c, p.gpsBits);
  }
  *last = p;
  last->gpsChanged = gpsChange;
}

void Point14Codec::encodeGps(Context& c, std::uint64_t gps) {
  ArithmeticEncoder& enc = *out_[kLGps].enc;
  auto fits32 = [](std::uint64_t a, std::uint64_t b, std::int32_t& d) {
    const auto d64 = static_cast<std::int64_t>(a - b);
    d = static_cast<std::int32_t>(static_cast<std::uint32_t>(static_cast<std::uint64_t>(d64)));
    return d64 == d;
  };
  for (;;) {
    const std::uint32_t L = c.gpsLast;
    std::int32_t d;
    const bool fits = fits32(gps, c.gps[L], d);
    const bool zeroDiff = c.gpsDiff[L] == 0;
    ArithmeticModel& selector = zeroDiff ? c.gpsZeroDiff : c.gpsMulti;
    if (fits) {
      if (zeroDiff) {
        enc.encodeSymbol(selector, 0);
        c.icGps.compress(enc, 0, d, 0);
        c.gpsDiff[L] = d;
        c.gpsExtreme[L] = 0;
      } else {
        // Multiplier between this difference and the last one, rounded half away from zero (clamped
        // first: anything beyond +-500 codes the same way and the float must stay convertible).
        float mf = static_cast<float>(d) / static_cast<float>(c.gpsDiff[L]);
        if (mf > 1.0e6f) mf = 1.0e6f;
        if (mf < -1.0e6f) mf = -1.0e6f;
        const auto multi = static_cast<std::int32_t>(mf >= 0.0f ? mf + 0.5f : mf - 0.5f);
        bool extreme = false;
        if (multi == 1) {
          enc.encodeSymbol(selector, 1);
          c.icGps.compress(enc, c.gpsDiff[L], d, 1);
          c.gpsExtreme[L] = 0;
        } else if (multi > 0) {
          if (multi < kGpsMulti) {
            enc.encodeSymbol(selector, static_cast<std::uint32_t>(multi));
            c.icGps.compress(enc, wrapMul(multi, c.gpsDiff[L]), d, multi < 10 ? 2 : 3);
          } else {
            enc.encodeSymbol(selector, kGpsMulti);
            c.icGps.compress(enc, wrapMul(kGpsMulti, c.gpsDiff[L]), d, 4);
            extreme = true;
          }
        } else if (multi < 0) {
          if (multi > kGpsMultiMinus) {
            enc.encodeSymbol(selector, static_cast<std::uint32_t>(kGpsMulti - multi));
            c.icGps.compress(enc, wrapMul(multi, c.gpsDiff[L]), d, 5);
          } else {
            enc.encodeSymbol(selector, static_cast<std::uint32_t>(kGpsMulti - kGpsMultiMinus));
            c.icGps.compress(enc, wrapMul(kGpsMultiMinus, c.gpsDiff[L]), d, 6);
            extreme = true;
          }
        } else {
          enc.encodeSymbol(selector, 0);
          c.icGps.compress(enc, 0, d, 7);
          extreme = true;
        }
        if (extreme && ++c.gpsExtreme[L] > 3) {
          c.gpsDiff[L] = d;
          c.gpsExtreme[L] = 0;
        }
      }
      c.gps[L] = gps;
      return;
    }
    // Too far from the current sequence: maybe it continues one of the other three.
    bool switched = false;
    for (std::uint32_t i = 1; i < 4; ++i) {
      std::int32_t od;
      if (fits32(gps, c.gps[(L + i) & 3], od)) {
        enc.encodeSymbol(selector, zeroDiff ? i + 1 : kGpsCodeFull + i);
        c.gpsLast = (L + i) & 3;
        switched = true;
        break;
      }
    }
    if (switched) continue;
    // Start a new sequence.
    enc.encodeSymbol(selector, zeroDiff ? 1u : kGpsCodeFull);
    c.icGps.compress(enc, static_cast<std::int32_t>(c.gps[L] >> 32), static_cast<std::int32_t>(gps >> 32), 8);
    enc.writeInt(static_cast<std::uint32_t>(gps));
    c.gpsNext = (c.gpsNext + 1) & 3;
    c.gpsLast = c.gpsNext;
    c.gpsDiff[c.gpsLast] = 0;
    c.gpsExtreme[c.gpsLast] = 0;
    c.gps[c.gpsLast] = gps;
    return;
  }
}

void Point14Codec::finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes) {
  for (OutLayer& l : out_) finishLayer(l, sizes, bytes);
}

// ---------------------------------------------------------------------------------------------------------
// RgbCodec
// ---------------------------------------------------------------------------------------------------------
struct RgbCodec::Context {
  std::array<std::uint16_t, 4> last{};
  ArithmeticModel rgbUsed{128};  // bit i (0..5): byte i of R,G,B changed; bit 6: G/B differ from R
  std::vector<ArithmeticModel> rgbDiff = std::vector<ArithmeticModel>(6, ArithmeticModel(256));
  ArithmeticModel nirUsed{4};
  std::vector<ArithmeticModel> nirDiff = std::vector<ArithmeticModel>(2, ArithmeticModel(256));
};

RgbCodec::RgbCodec(bool withNir) : withNir_(withNir) {}
RgbCodec::~RgbCodec() = default;

[[gnu::noinline]] void RgbCodec::initContext(std::uint32_t index, const std::uint16_t* seed) {
  if (!ctx_[index]) ctx_[index] = std::make_unique<Context>();
  Context& c = *ctx_[index];
  if (encoding_ || in_[0].active) {
    c.rgbUsed.reset();
    for (auto& m : c.rgbDiff) m.reset();
  }
  if (encoding_ || in_[1].active) {
    c.nirUsed.reset();
    for (auto& m : c.nirDiff) m.reset();
  }
  std::memcpy(c.last.data(), seed, 8);
  used_[index] = true;
}

RgbCodec::Context& RgbCodec::switchTo(std::uint32_t channel, std::uint16_t*& last) {
  last = ctx_[cur_]->last.data();
  if (channel != cur_) {
    const std::uint32_t previous = cur_;
    cur_ = channel;
    if (!used_[channel]) {
      initContext(channel, ctx_[previous]->last.data());
      last = ctx_[channel]->last.data();
    }
  }
  return *ctx_[cur_];
}

void RgbCodec::beginDecode(const std::uint8_t* firstItem, const std::uint8_t* const* layerData,
                           const std::uint32_t* layerSize, std::uint32_t layers, std::uint32_t channel) {
  std::array<std::uint16_t, 4> seed{};
  std::memcpy(seed.data(), firstItem, itemSize());
  encoding_ = false;
  startLayer(in_[0], layerData[0], layerSize[0], layers & kRgb);
  if (withNir_) startLayer(in_[1], layerData[1], layerSize[1], layers & kNir);
  used_.fill(false);
  cur_ = channel;
  initContext(channel, seed.data());
}

const char* RgbCodec::damagedLayer() const {
  if (in_[0].damaged()) return "RGB";
  if (in_[1].damaged()) return "NIR";
  return nullptr;
}

[[gnu::flatten]] void RgbCodec::decodeNext(std::uint32_t channel, std::uint8_t* item) {
  std::uint16_t* L;
  Context& c = switchTo(channel, L);
  if (in_[0].active) {
    ArithmeticDecoder& d = in_[0].dec;
    const std::uint32_t sym = d.decodeSymbol(c.rgbUsed);
    const std::int32_t l0 = L[0] & 0xFF, h0 = L[0] >> 8, l1 = L[1] & 0xFF, h1 = L[1] >> 8, l2 = L[2] & 0xFF,
                       h2 = L[2] >> 8;
    std::int32_t rl = l0, rh = h0;
    if (sym & 1) rl = decodeByte(d, c.rgbDiff[0], l0);
    if (sym & 2) rh = decodeByte(d, c.rgbDiff[1], h0);
    std::int32_t gl = rl, gh = rh, bl = rl, bh = rh;
    if (sym & 64) {  // green and blue are predicted from red's change
      std::int32_t dl = rl - l0;
      gl = l1;
      if (sym & 4) gl = decodeByte(d, c.rgbDiff[2], clamp8(dl + l1));
      bl = l2;
      if (sym & 16) {
        dl = (dl + gl - l1) / 2;
        bl = decodeByte(d, c.rgbDiff[4], clamp8(dl + l2));
      }
      std::int32_t dh = rh - h0;
      gh = h1;
      if (sym & 8) gh = decodeByte(d, c.rgbDiff[3], clamp8(dh + h1));
      bh = h2;
      if (sym & 32) {
        dh = (dh + gh - h1) / 2;
        bh = decodeByte(d, c.rgbDiff[5], clamp8(dh + h2));
      }
    }
    L[0] = static_cast<std::uint16_t>(rl | (rh << 8));
    L[1] = static_cast<std::uint16_t>(gl | (gh << 8));
    L[2] = static_cast<std::uint16_t>(bl | (bh << 8));
  }
  if (withNir_ && in_[1].active) {
    ArithmeticDecoder& d = in_[1].dec;
    const std::uint32_t sym = d.decodeSymbol(c.nirUsed);
    std::int32_t lo = L[3] & 0xFF, hi = L[3] >> 8;
    if (sym & 1) lo = decodeByte(d, c.nirDiff[0], lo);
    if (sym & 2) hi = decodeByte(d, c.nirDiff[1], hi);
    L[3] = static_cast<std::uint16_t>(lo | (hi << 8));
  }
  std::memcpy(item, L, itemSize());
}

void RgbCodec::beginEncode(const std::uint8_t* firstItem, std::uint32_t channel) {
  std::array<std::uint16_t, 4> seed{};
  std::memcpy(seed.data(), firstItem, itemSize());
  encoding_ = true;
  used_.fill(false);
  cur_ = channel;
  initContext(channel, seed.data());
  out_[0].start();
  if (withNir_) out_[1].start();
}

void RgbCodec::encodeNext(std::uint32_t channel, const std::uint8_t* item) {
  std::uint16_t* L;
  Context& c = switchTo(channel, L);
  std::array<std::uint16_t, 4> v{};
  std::memcpy(v.data(), item, itemSize());
  {
    ArithmeticEncoder& e = *out_[0].enc;
    const std::int32_t l0 = L[0] & 0xFF, h0 = L[0] >> 8, l1 = L[1] & 0xFF, h1 = L[1] >> 8, l2 = L[2] & 0xFF,
                       h2 = L[2] >> 8;
    const std::int32_t rl = v[0] & 0xFF, rh = v[0] >> 8, gl = v[1] & 0xFF, gh = v[1] >> 8, bl = v[2] & 0xFF,
                       bh = v[2] >> 8;
    std::uint32_t sym = (rl != l0 ? 1u : 0u) | (rh != h0 ? 2u : 0u) | (gl != l1 ? 4u : 0u) |
                        (gh != h1 ? 8u : 0u) | (bl != l2 ? 16u : 0u) | (bh != h2 ? 32u : 0u);
    if (rl != gl || rl != bl || rh != gh || rh != bh) sym |= 64;
    e.encodeSymbol(c.rgbUsed, sym);
    std::int32_t dl = 0, dh = 0;
    if (sym & 1) {
      dl = rl - l0;
      e.encodeSymbol(c.rgbDiff[0], fold8(dl));
    }
    if (sym & 2) {
      dh = rh - h0;
      e.encodeSymbol(c.rgbDiff[1], fold8(dh));
    }
    if (sym & 64) {
      if (sym & 4) e.encodeSymbol(c.rgbDiff[2], fold8(gl - clamp8(dl + l1)));
      if (sym & 16) {
        dl = (dl + gl - l1) / 2;
        e.encodeSymbol(c.rgbDiff[4], fold8(bl - clamp8(dl + l2)));
      }
      if (sym & 8) e.encodeSymbol(c.rgbDiff[3], fold8(gh - clamp8(dh + h1)));
      if (sym & 32) {
        dh = (dh + gh - h1) / 2;
        e.encodeSymbol(c.rgbDiff[5], fold8(bh - clamp8(dh + h2)));
      }
    }
    if (sym) out_[0].changed = true;
  }
  if (withNir_) {
    ArithmeticEncoder& e = *out_[1].enc;
    const std::int32_t lo = L[3] & 0xFF, hi = L[3] >> 8, nl = v[3] & 0xFF, nh = v[3] >> 8;
    const std::uint32_t sym = (nl != lo ? 1u : 0u) | (nh != hi ? 2u : 0u);
    e.encodeSymbol(c.nirUsed, sym);
    if (sym & 1) e.encodeSymbol(c.nirDiff[0], fold8(nl - lo));
    if (sym & 2) e.encodeSymbol(c.nirDiff[1], fold8(nh - hi));
    if (sym) out_[1].changed = true;
  }
  std::memcpy(L, v.data(), 8);
}

void RgbCodec::finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes) {
  finishLayer(out_[0], sizes, bytes);
  if (withNir_) finishLayer(out_[1], sizes, bytes);
}

// ---------------------------------------------------------------------------------------------------------
// WavePacketCodec
// ---------------------------------------------------------------------------------------------------------
struct WavePacketCodec::Context {
  std::array<std::uint8_t, 29> last{};
  std::int32_t lastOffsetDiff = 0;   // last explicitly coded 32-bit offset difference
  std::uint32_t lastOffsetKind = 0;  // how the previous offset was coded (selects the model below)
  ArithmeticModel packetIndex{256};
  std::vector<ArithmeticModel> offsetKind = std::vector<ArithmeticModel>(4, ArithmeticModel(4));
  IntegerCompressor icOffsetDiff{32}, icPacketSize{32}, icReturnPoint{32}, icXyz{32, 3};
};

namespace {
// The 28 bytes after the descriptor index: offset (u64), size (u32), return point and dx/dy/dz (f32 coded
// as their 32-bit patterns).
struct WavePacketFields {
  std::uint64_t offset;
  std::uint32_t size;
  std::int32_t returnPoint, x, y, z;
  static WavePacketFields load(const std::uint8_t* p) {
    return {loadLE<std::uint64_t>(p),     loadLE<std::uint32_t>(p + 8), loadLE<std::int32_t>(p + 12),
            loadLE<std::int32_t>(p + 16), loadLE<std::int32_t>(p + 20), loadLE<std::int32_t>(p + 24)};
  }
  void store(std::uint8_t* p) const {
    storeLE(p, offset);
    storeLE(p + 8, size);
    storeLE(p + 12, returnPoint);
    storeLE(p + 16, x);
    storeLE(p + 20, y);
    storeLE(p + 24, z);
  }
};
}  // namespace

WavePacketCodec::WavePacketCodec() = default;
WavePacketCodec::~WavePacketCodec() = default;

[[gnu::noinline]] void WavePacketCodec::initContext(std::uint32_t index, const std::uint8_t* seed) {
  if (!ctx_[index]) ctx_[index] = std::make_unique<Context>();
  Context& c = *ctx_[index];
  if (encoding_ || in_.active) {
    c.packetIndex.reset();
    for (auto& m : c.offsetKind) m.reset();
    c.icOffsetDiff.initDecompressor();
    c.icPacketSize.initDecompressor();
    c.icReturnPoint.initDecompressor();
    c.icXyz.initDecompressor();
  }
  c.lastOffsetDiff = 0;
  c.lastOffsetKind = 0;
  std::memcpy(c.last.data(), seed, 29);
  used_[index] = true;
}

WavePacketCodec::Context& WavePacketCodec::switchTo(std::uint32_t channel, std::uint8_t*& last) {
  last = ctx_[cur_]->last.data();
  if (channel != cur_) {
    const std::uint32_t previous = cur_;
    cur_ = channel;
    if (!used_[channel]) {
      initContext(channel, ctx_[previous]->last.data());
      last = ctx_[channel]->last.data();
    }
  }
  return *ctx_[cur_];
}

void WavePacketCodec::beginDecode(const std::uint8_t* firstItem, const std::uint8_t* layerData,
                                  std::uint32_t layerSize, std::uint32_t layers, std::uint32_t channel) {
  encoding_ = false;
  startLayer(in_, layerData, layerSize, layers & kWavePacket);
  used_.fill(false);
  cur_ = channel;
  initContext(channel, firstItem);
}

const char* WavePacketCodec::damagedLayer() const {
  return in_.damaged() ? "wave packet" : nullptr;
}

void WavePacketCodec::decodeNext(std::uint32_t channel, std::uint8_t* item) {
  std::uint8_t* L;
  Context& c = switchTo(channel, L);
  if (in_.active) {
    ArithmeticDecoder& d = in_.dec;
    const WavePacketFields last = WavePacketFields::load(L + 1);
    WavePacketFields cur;
    L[0] = static_cast<std::uint8_t>(d.decodeSymbol(c.packetIndex));
    c.lastOffsetKind = d.decodeSymbol(c.offsetKind[c.lastOffsetKind]);
    switch (c.lastOffsetKind) {
      case 0:  // same offset
        cur.offset = last.offset;
        break;
      case 1:  // packed right after the previous packet
        cur.offset = last.offset + last.size;
        break;
      case 2:
        c.lastOffsetDiff = c.icOffsetDiff.decompress(d, c.lastOffsetDiff);
        cur.offset = last.offset + static_cast<std::uint64_t>(static_cast<std::int64_t>(c.lastOffsetDiff));
        break;
      default:
        cur.offset = d.readInt64();
        break;
    }
    cur.size = static_cast<std::uint32_t>(c.icPacketSize.decompress(d, static_cast<std::int32_t>(last.size)));
    cur.returnPoint = c.icReturnPoint.decompress(d, last.returnPoint);
    cur.x = c.icXyz.decompress(d, last.x, 0);
    cur.y = c.icXyz.decompress(d, last.y, 1);
    cur.z = c.icXyz.decompress(d, last.z, 2);
    cur.store(L + 1);
  }
  std::memcpy(item, L, 29);
}

void WavePacketCodec::beginEncode(const std::uint8_t* firstItem, std::uint32_t channel) {
  encoding_ = true;
  used_.fill(false);
  cur_ = channel;
  initContext(channel, firstItem);
  out_.start();
}

void WavePacketCodec::encodeNext(std::uint32_t channel, const std::uint8_t* item) {
  std::uint8_t* L;
  Context& c = switchTo(channel, L);
  ArithmeticEncoder& e = *out_.enc;
  if (std::memcmp(item, L, 29) != 0) out_.changed = true;
  e.encodeSymbol(c.packetIndex, item[0]);
  const WavePacketFields cur = WavePacketFields::load(item + 1);
  const WavePacketFields last = WavePacketFields::load(L + 1);
  const auto diff64 = static_cast<std::int64_t>(cur.offset - last.offset);
  const auto diff32 =
      static_cast<std::int32_t>(static_cast<std::uint32_t>(static_cast<std::uint64_t>(diff64)));
  std::uint32_t kind;
  if (diff64 == diff32) {
    kind = diff32 == 0 ? 0u : (diff32 == static_cast<std::int32_t>(last.size) ? 1u : 2u);
  } else {
    kind = 3;
  }
  e.encodeSymbol(c.offsetKind[c.lastOffsetKind], kind);
  c.lastOffsetKind = kind;
  if (kind == 2) {
    c.icOffsetDiff.compress(e, c.lastOffsetDiff, diff32);
    c.lastOffsetDiff = diff32;
  } else if (kind == 3) {
    e.writeInt64(cur.offset);
  }
  c.icPacketSize.compress(e, static_cast<std::int32_t>(last.size), static_cast<std::int32_t>(cur.size));
  c.icReturnPoint.compress(e, last.returnPoint, cur.returnPoint);
  c.icXyz.compress(e, last.x, cur.x, 0);
  c.icXyz.compress(e, last.y, cur.y, 1);
  c.icXyz.compress(e, last.z, cur.z, 2);
  std::memcpy(L, item, 29);
}

void WavePacketCodec::finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes) {
  finishLayer(out_, sizes, bytes);
}

// ---------------------------------------------------------------------------------------------------------
// ByteCodec
// ---------------------------------------------------------------------------------------------------------
struct ByteCodec::Context {
  std::vector<std::uint8_t> last;
  std::vector<ArithmeticModel> models;
};

ByteCodec::ByteCodec(std::uint32_t count) : count_(count), in_(count), out_(count) {}
ByteCodec::~ByteCodec() = default;

[[gnu::noinline]] void ByteCodec::initContext(std::uint32_t index, const std::uint8_t* seed) {
  if (!ctx_[index]) {
    ctx_[index] = std::make_unique<Context>();
    ctx_[index]->last.resize(count_);
    ctx_[index]->models.assign(count_, ArithmeticModel(256));
  }
  Context& c = *ctx_[index];
  for (std::uint32_t i = 0; i < count_; ++i)
    if (encoding_ || in_[i].active) c.models[i].reset();
  std::memcpy(c.last.data(), seed, count_);
  used_[index] = true;
}

ByteCodec::Context& ByteCodec::switchTo(std::uint32_t channel, std::uint8_t*& last) {
  last = ctx_[cur_]->last.data();
  if (channel != cur_) {
    const std::uint32_t previous = cur_;
    cur_ = channel;
    if (!used_[channel]) {
      initContext(channel, ctx_[previous]->last.data());
      last = ctx_[channel]->last.data();
    }
  }
  return *ctx_[cur_];
}

void ByteCodec::beginDecode(const std::uint8_t* firstItem, const std::uint8_t* const* layerData,
                            const std::uint32_t* layerSize, std::uint32_t layers, std::uint32_t channel) {
  encoding_ = false;
  for (std::uint32_t i = 0; i < count_; ++i)
    startLayer(in_[i], layerData[i], layerSize[i], layers & kExtraBytes);
  used_.fill(false);
  cur_ = channel;
  initContext(channel, firstItem);
}

const char* ByteCodec::damagedLayer() const {
  for (const InLayer& l : in_)
    if (l.damaged()) return "extra byte";
  return nullptr;
}

void ByteCodec::decodeNext(std::uint32_t channel, std::uint8_t* item) {
  std::uint8_t* L;
  Context& c = switchTo(channel, L);
  for (std::uint32_t i = 0; i < count_; ++i) {
    if (in_[i].active) L[i] = static_cast<std::uint8_t>(L[i] + in_[i].dec.decodeSymbol(c.models[i]));
    item[i] = L[i];
  }
}

void ByteCodec::beginEncode(const std::uint8_t* firstItem, std::uint32_t channel) {
  encoding_ = true;
  used_.fill(false);
  cur_ = channel;
  initContext(channel, firstItem);
  for (OutLayer& l : out_) l.start();
}

void ByteCodec::encodeNext(std::uint32_t channel, const std::uint8_t* item) {
  std::uint8_t* L;
  Context& c = switchTo(channel, L);
  for (std::uint32_t i = 0; i < count_; ++i) {
    const std::uint8_t diff = static_cast<std::uint8_t>(item[i] - L[i]);
    out_[i].enc->encodeSymbol(c.models[i], diff);
    if (diff) {
      out_[i].changed = true;
      L[i] = item[i];
    }
  }
}

void ByteCodec::finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes) {
  for (OutLayer& l : out_) finishLayer(l, sizes, bytes);
}

}  // namespace tinbuild::laz::layered
