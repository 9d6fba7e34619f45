// Breaklines and hydro-flattening in a job (header).
#include "app/jobs/constraints.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <thread>
#ifdef __GLIBC__
#include <malloc.h>
#endif

#include "formats/crs/crs.h"
#include "formats/crs/reprojection.h"
#include "formats/io/output_file.h"
#include "formats/io/record_file.h"
#include "formats/vector/constraint_reader.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"

namespace tinbuild {

namespace {

// The pass before the finalizer: the kept points' extent and count, and the bank points.
struct SurveyPass {
  Bounds3 bounds;
  std::uint64_t points = 0;
};

SurveyPass passOverPoints(Survey& survey, const PointFilter& filter, ShoreSampler* sampler, const CancelFlag* cancel,
                          const ShoreSampler* candidates = nullptr, std::vector<PointRecord>* gathered = nullptr) {
  SurveyPass out;
  PointFilter userFilter = filter;
  userFilter.stages.clear();
  userFilter.window.reset();
  std::vector<PointRecord> batch(65536);
  FilterCounts counts;
  for (PointStream* s : survey.streams) {
    s->setDecodeThreads(std::max(1, static_cast<int>(std::thread::hardware_concurrency())));  // (the finalizer sets its own)
    if (!s->rewindable())
      throw UsageError("--breaklines/--water read the survey once before the run: the input must be a file, not stdin");
    s->rewind();  // (in the finalizer's count pass, the input may stand anywhere: its first pass spooled it)
    for (;;) {
      throwIfCancelled(cancel);
      std::size_t n = s->read(batch.data(), batch.size());
      if (n == 0) break;
      n = userFilter.apply(batch.data(), n, counts);
      for (std::size_t i = 0; i < n; ++i) out.bounds.add(batch[i].x, batch[i].y, batch[i].z);
      out.points += n;
      if (sampler) sampler->add(batch.data(), n);
      if (candidates) candidates->collect(batch.data(), n, *gathered);
    }
    s->rewind();
  }
  return out;
}

std::vector<ConstraintSegment> breaklineSegments(const ConstraintInput& in) {
  std::vector<ConstraintSegment> out;
  for (std::uint32_t i = 0; i < in.breaklines.size(); ++i) {
    const ConstraintLine& l = in.breaklines[i];
    const std::size_t n = l.points.size();
    for (std::size_t k = 0; k + 1 < n; ++k) out.push_back({l.points[k], l.points[k + 1], SegmentKind::Breakline, i});
    if (l.closed && n >= 3) out.push_back({l.points[n - 1], l.points[0], SegmentKind::Breakline, i});
  }
  return out;
}

double lengthOption(const std::string& text, double fallback, const CrsInfo& crs, const char* option) {
  if (text.empty()) return fallback;
  const double v = parseLength(text, crs, option);
  if (!(v > 0) || !std::isfinite(v)) throw UsageError(std::string(option) + " must be a positive length, got '" + text + "'");
  return v;
}

// A constraint length far below the survey's point spacing is no spacing a survey supports: a value in the
// wrong unit or a slip (1e-6 for 1), which would make the preparation run for hours.  Refused at once, in
// the style of --step and --interval, naming the least value that makes sense.
void checkLengthFloor(const std::string& text, double value, double spacing, const char* option,
                      const char* consequence) {
  if (text.empty() || !(spacing > 0)) return;
  const double least = spacing / 10;
  if (value < least)
    throw UsageError(std::string(option) + " " + text + " is below a tenth of the survey's point spacing (" +
                     formatDouble("%.6g", spacing) + "): " + consequence + "; give at least " +
                     formatDouble("%.6g", least) + " (or a length with its unit, e.g. 2m, 6ft)");
}

void checkConstraintLengths(const ConstraintRequest& q, const CrsInfo& crs, double spacing) {
  if (!q.stationSpacing.empty())
    checkLengthFloor(q.stationSpacing, lengthOption(q.stationSpacing, 1, crs, "--station-spacing"), spacing,
                     "--station-spacing",
                     "stations that close share their bank points, and there would be millions");
  if (!q.buffer.empty())
    checkLengthFloor(q.buffer, lengthOption(q.buffer, 1, crs, "--breakline-buffer"), spacing,
                     "--breakline-buffer",
                     "pieces that short hold no lidar point between them, and there would be millions");
  if (!q.shoreDistance.empty())
    checkLengthFloor(q.shoreDistance, lengthOption(q.shoreDistance, 1, crs, "--shore-distance"), spacing,
                     "--shore-distance", "a band that narrow holds no bank point to set a level");
}

constexpr char kMagic[8] = {'T', 'B', 'C', 'O', 'N', 'S', '0', '2'};

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

}  // namespace

// ---------------------------------------------------------------------------------------------------
// ConstraintPreparation

struct ConstraintPreparation::State {
  const PipelineOptions& o;
  Survey& survey;
  Diagnostics& diag;
  ConstraintInput input;
  PreparedConstraints c;
  WaterLevelOptions wo;
  std::unique_ptr<ShoreSampler> sampler;  // the real one (with --water), once its lengths are known
  std::unique_ptr<ShoreSampler> gather;   // the points near the shores, within the wide band (below)
  WaterLevelOptions wide;
  std::vector<PointRecord> near;
  double demStep = 0;
  bool fold = false;  // the points come through observe()
  double observeSeconds = 0;

  State(const PipelineOptions& options, Survey& s, Diagnostics& d) : o(options), survey(s), diag(d) {}

  static double spacingOf(const Bounds3& b, std::uint64_t n) {
    const double area = std::max((b.maxX - b.minX) * (b.maxY - b.minY), 1e-12);
    return std::sqrt(area / static_cast<double>(std::max<std::uint64_t>(n, 1)));
  }
  // Lengths in metres, in CRS units (a survey without a CRS: metres).
  double metres(double m) const {
    return survey.crs.geographic ? m : parseLength(formatDouble("%.17g", m) + "m", survey.crs, "(a length)");
  }
  void makeSampler(double sp) {
    const ConstraintRequest& q = o.constraints;
    wo.shoreDistance = lengthOption(q.shoreDistance, std::max({metres(3), 3 * demStep, 3 * sp}), survey.crs,
                                    "--shore-distance");
    wo.stationSpacing = lengthOption(q.stationSpacing, 10 * sp, survey.crs, "--station-spacing");
    wo.spacing = sp;
    wo.margin = 2 * sp;
    // (heights: in the unit of z, which may differ from the horizontal one)
    const double zMetre = survey.zUnitToMetre > 0 ? survey.zUnitToMetre : 1;
    wo.outlierDepth = 0.05 / zMetre;
    wo.sectionRise = 0.01 / zMetre;
    sampler = std::make_unique<ShoreSampler>(input, wo);
  }
  // The sampler when some level must come from the points (none when every level is given).
  ShoreSampler* sampling() const { return sampler && sampler->needsPoints() ? sampler.get() : nullptr; }
};

ConstraintPreparation::ConstraintPreparation(const PipelineOptions& o, Survey& survey, Diagnostics& diag)
    : s_(std::make_unique<State>(o, survey, diag)) {
  State& st = *s_;
  const ConstraintRequest& q = o.constraints;
  if (!q.any()) {
    if (!q.flows.empty()) throw UsageError("--flow needs --water (the rivers' polygons)");
    return;
  }
  const auto t = Clock::now();
  ConstraintFiles files;
  files.breaklines = q.breaklines;
  files.water = q.water;
  files.flows = q.flows;
  files.cancel = o.finalizer.cancel;
  st.input = readConstraints(files, survey.crs, diag);
  // Comparing and transforming the layers' CRSs opened PROJ's database (its SQLite page cache, about 2 MB,
  // stayed resident for the whole run): released as after opening the inputs (survey.cpp).
  releaseCrsCaches(survey.transforms.empty());
  st.c.breaklines = st.input.breaklines.size();
  st.c.readSeconds = since(t);
  if (!survey.crs.wkt.empty() && survey.crs.geographic)
    throw UsageError("--breaklines/--water need a projected CRS (lengths in metres): give --t_srs");
  st.wo.percentile = q.percentile;
  st.wo.cancel = o.finalizer.cancel;
  // The lengths the user gave, against the spacing the headers promise (every point of the survey: the
  // kept points' spacing is at least that) before any work; again in finish() with the kept points'.
  if (survey.headerBounds && survey.headerPoints > 0)
    checkConstraintLengths(q, survey.crs, State::spacingOf(*survey.headerBounds, survey.headerPoints));
  // The bank band: at least 3 m, 3 DEM pixels and 3 point spacings (the specification's "immediately
  // surrounding terrain", checked on the product: bank_check.h).
  if (!o.dem.path.empty()) {
    try {
      st.demStep = parseLength(o.dem.step, survey.crs, "--step");
    } catch (const UsageError&) {
      st.demStep = 0;  // (said by the DEM's own check, later)
    }
  }
  // The points: the spacing needs the extent and count of the kept points; the bank points need the
  // shore distance, which defaults to a multiple of that spacing.  They can come in the finalizer's count
  // pass (observe) when both lengths are given, or when the header's spacing bounds the default: the
  // points near the shores are gathered within twice the default distance for the header's spacing
  // (every point of the survey: the kept points' spacing, and so the default distance, is larger only
  // when the filters keep less than a quarter of the points); then the real sampler takes the gathered
  // points (the same as a pass of its own would give it), else finish() reads the survey once more.
  // Without either (no header bounds), prepare() makes the passes itself.
  if (q.water.empty()) {
    st.fold = true;  // (breaklines alone: the extent and count only)
  } else if (!q.shoreDistance.empty() && !q.stationSpacing.empty()) {
    st.makeSampler(1);  // (both lengths given: the spacing is not needed)
    st.fold = true;
  } else if (survey.headerBounds && survey.headerPoints > 0) {
    const double headerSpacing = State::spacingOf(*survey.headerBounds, survey.headerPoints);
    st.wide = st.wo;
    st.wide.shoreDistance = q.shoreDistance.empty()
                                ? std::max({st.metres(3), 3 * st.demStep, 6 * headerSpacing})
                                : lengthOption(q.shoreDistance, 1, survey.crs, "--shore-distance");
    st.wide.margin = 4 * headerSpacing;
    st.wide.stationSpacing = 1;
    st.gather = std::make_unique<ShoreSampler>(st.input, st.wide);
    if (!st.gather->needsPoints()) st.gather.reset();
    st.fold = true;
  }
}

ConstraintPreparation::~ConstraintPreparation() = default;

bool ConstraintPreparation::any() const {
  return s_->o.constraints.any();
}
bool ConstraintPreparation::foldable() const {
  return any() && s_->fold;
}

void ConstraintPreparation::observe(const PointRecord* p, std::size_t n) {
  State& st = *s_;
  const auto t = Clock::now();
  if (st.gather)
    st.gather->collect(p, n, st.near);
  else if (ShoreSampler* sm = st.sampling())
    sm->add(p, n);
  st.observeSeconds += since(t);
}

PreparedConstraints ConstraintPreparation::prepare() {
  State& st = *s_;
  if (!any()) return {};
  // The pass (see the constructor): the kept points' extent and count, and what observe() would take.
  const auto t = Clock::now();
  const SurveyPass pass =
      passOverPoints(st.survey, st.o.finalizer.filter, st.gather ? nullptr : st.sampling(),
                     st.o.finalizer.cancel, st.gather.get(), &st.near);
  st.observeSeconds = since(t);
  return finish(pass.bounds, pass.points);
}

PreparedConstraints ConstraintPreparation::finish(const Bounds3& bounds, std::uint64_t points) {
  State& st = *s_;
  const ConstraintRequest& q = st.o.constraints;
  PreparedConstraints& c = st.c;
  auto t = Clock::now();
  const double spacing = State::spacingOf(bounds, points);
  if (points == 0)
    throw DataError(st.o.inputs.empty() ? "build" : st.o.inputs.front(),
                    "no point is kept by the filters: nothing to constrain");
  if (!q.water.empty()) {
    const bool fed = st.sampler != nullptr;  // (both lengths given: it took the points as they came)
    if (!st.sampler) st.makeSampler(spacing);
    ShoreSampler* sm = st.sampling();
    if (sm && !fed) {
      if (st.gather && st.wo.shoreDistance + st.wo.margin <= st.wide.shoreDistance + st.wide.margin)
        sm->add(st.near.data(), st.near.size());
      else  // (no header to gather by, or filters that keep less than a quarter: one more pass)
        passOverPoints(st.survey, st.o.finalizer.filter, sm, st.o.finalizer.cancel);
    }
  }
  std::vector<PointRecord>().swap(st.near);
  st.gather.reset();
  checkConstraintLengths(q, st.survey.crs, spacing);
  c.passSeconds = st.observeSeconds + since(t);
  t = Clock::now();
  c.spacing = spacing;
  c.shoreDistance = st.wo.shoreDistance;
  c.band = st.wo.shoreDistance;
  c.stationSpacing = st.wo.stationSpacing;
  c.buffer = lengthOption(q.buffer, spacing, st.survey.crs, "--breakline-buffer");

  std::vector<ConstraintSegment> segments;
  if (!st.input.water.empty()) {
    const PreparedWater water = st.sampler->finish(bounds);
    for (const auto& [kind, message] : water.warnings) st.diag.warn(kind, "", message);
    segments = water.segments;
    c.water = water.areas;
    c.bodies = water.bodies;
    c.outliers = water.outliers;
  }
  st.sampler.reset();  // (its bank points and indexes: not needed past the levels)
  const std::vector<ConstraintSegment> lines = breaklineSegments(st.input);
  segments.insert(segments.end(), lines.begin(), lines.end());
  ConformingOptions co;
  co.minX = bounds.minX;
  co.minY = bounds.minY;
  co.maxX = bounds.maxX;
  co.maxY = bounds.maxY;
  co.maxPiece = c.buffer;
  co.snap = std::min(1e-3, c.buffer * 1e-3);
  co.cancel = st.o.finalizer.cancel;
  c.conforming = std::make_shared<const ConformingConstraints>(conformConstraints(segments, c.water, co));
  c.conformSeconds = since(t);
#ifdef __GLIBC__
  // The preparation's scratch (the points near the shores, the bank points, the split's work) is freed
  // now; hand the heap's free pages back, so the run's peak does not carry them.
  malloc_trim(0);
#endif
  if (c.conforming->vertices.empty())
    st.diag.warn("constraints.outside", q.breaklines.empty() ? q.water.front() : q.breaklines.front(),
                 "no constraint meets the survey's extent: nothing is constrained");
  return std::move(c);
}

PreparedConstraints prepareConstraints(const PipelineOptions& o, Survey& survey, Diagnostics& diag) {
  ConstraintPreparation prep(o, survey, diag);
  return prep.prepare();
}

namespace {
// The stages of the constraints, in their order (water, bank outliers, breaklines' buffers).
std::vector<std::shared_ptr<const PointStage>> constraintStages(const PreparedConstraints& c) {
  std::vector<std::shared_ptr<const PointStage>> stages;
  if (!c.water.empty()) stages.push_back(std::make_shared<WaterStage>(c.water));
  if (!c.outliers.empty()) stages.push_back(std::make_shared<BankOutlierStage>(c.outliers));
  stages.push_back(std::make_shared<BufferStage>(c.conforming));
  return stages;
}
const char* const kVerticesName = "the constraint vertices";
}  // namespace

void applyConstraints(const PreparedConstraints& c, FinalizerOptions& fo, Survey& survey) {
  if (c.empty()) return;
  for (auto& stage : constraintStages(c)) fo.filter.stages.push_back(std::move(stage));
  if (fo.filter.stages.size() > kMaxPointStages)
    throw UsageError("at most " + std::to_string(kMaxPointStages) + " point stages in one run");
  survey.addedStreams.push_back(std::make_unique<ConstraintStream>(c.conforming));
  survey.streams.push_back(survey.addedStreams.back().get());
  survey.names.push_back(kVerticesName);
  fo.inputNames = survey.names;
  if (fo.knownBounds)
    for (const ConstraintPoint& v : c.conforming->vertices) fo.knownBounds->add(v.x, v.y, v.z);
  if (fo.expectedPoints) fo.expectedPoints += c.conforming->vertices.size();
}

LateStages lateConstraints(const PreparedConstraints& c, Survey& survey) {
  LateStages late;
  if (c.empty()) return late;
  late.stages = constraintStages(c);
  survey.addedStreams.push_back(std::make_unique<ConstraintStream>(c.conforming));
  late.input = survey.addedStreams.back().get();
  late.inputName = kVerticesName;
  return late;
}

bool foldConstraints(ConstraintPreparation& prep, FinalizerOptions& fo, Survey& survey,
                     PreparedConstraints& out, std::shared_ptr<BankCheck> bankCheck,
                     std::vector<std::string>& stageNames) {
  if (!prep.foldable()) return false;
  if (fo.filter.stages.size() + 3 > kMaxPointStages)
    throw UsageError("at most " + std::to_string(kMaxPointStages) + " point stages in one run");
  fo.countBlocks = false;  // (the count pass reads the points: no counting from a hierarchy)
  fo.countObserver = [&prep](const PointRecord* p, std::size_t n) { prep.observe(p, n); };
  fo.lateStages = [&prep, &survey, &out, bankCheck, &stageNames](const Bounds3& kept, std::uint64_t n) {
    out = prep.finish(kept, n);
    if (bankCheck && !out.bodies.empty()) bankCheck->configure(out.water, out.bodies, out.band, out.spacing);
    LateStages late = lateConstraints(out, survey);
    for (const auto& stage : late.stages) stageNames.push_back(stage->name());
    return late;
  };
  return true;
}

void reportConstraints(const PreparedConstraints& c, RunReport& r) {
  if (c.empty()) return;
  ConstraintFigures& f = r.constraints;
  f.present = true;
  f.breaklines = c.breaklines;
  f.vertices = c.conforming->vertices.size();
  f.pieces = c.conforming->pieces.size();
  f.crossings = c.conforming->stats.crossings;
  f.spacing = c.spacing;
  f.buffer = c.buffer;
  f.shoreDistance = c.shoreDistance;
  f.stationSpacing = c.stationSpacing;
  f.bodies = c.bodies;
  f.band = c.band;
  f.readSeconds = c.readSeconds;
  f.passSeconds = c.passSeconds;
  f.conformSeconds = c.conformSeconds;
}

void writeConstraints(const PreparedConstraints& c, const std::string& path) {
  OutputFile f(path);
  auto u64 = [&f](std::uint64_t v) { f.write(&v, 8); };
  auto f64 = [&f](double v) { f.write(&v, 8); };
  f.write(kMagic, 8);
  f64(c.spacing);
  f64(c.buffer);
  f64(c.shoreDistance);
  f64(c.stationSpacing);
  u64(c.breaklines);
  const auto& v = c.conforming->vertices;
  u64(v.size());
  for (const auto& p : v) {
    f64(p.x);
    f64(p.y);
    f64(p.z);
  }
  const auto& pcs = c.conforming->pieces;
  u64(pcs.size());
  for (const auto& p : pcs) f.write(p.data(), 8);
  u64(c.water.size());
  auto ring = [&](const std::vector<std::array<double, 2>>& r) {
    u64(r.size());
    for (const auto& q : r) {
      f64(q[0]);
      f64(q[1]);
    }
  };
  for (const WaterArea& w : c.water) {
    ring(w.outer);
    u64(w.holes.size());
    for (const auto& h : w.holes) ring(h);
  }
  u64(c.bodies.size());
  for (const WaterBody& b : c.bodies) {
    u64(b.source.size());
    f.write(b.source.data(), b.source.size());
    u64((b.river ? 1u : 0u) | (b.given ? 2u : 0u));
    f64(b.level);
    f64(b.lastLevel);
    u64(b.bankPoints);
    u64(b.stations);
    u64(b.body);
    u64(b.members);
    u64(b.area);
    u64(b.outliers);
    u64(b.profile ? 1 : 0);
    if (b.profile) {
      const RiverProfile& p = *b.profile;
      ring(p.centreline);
      f64(p.s0);
      f64(p.step);
      u64(p.sections);
      u64(p.level.size());
      for (std::size_t k = 0; k < p.level.size(); ++k) {
        f64(p.raw[k]);
        f64(p.level[k]);
        u64(p.points[k]);
      }
    }
  }
  u64(c.outliers.size());
  for (const ConstraintPoint& p : c.outliers) {
    f64(p.x);
    f64(p.y);
    f64(p.z);
  }
  f64(c.band);
  f.write(kMagic, 8);  // (the end: a file cut short is found)
  f.commit();
}

PreparedConstraints readConstraintsFile(const std::string& path) {
  RecordReader in(path, "constraint file");
  char magic[8];
  in.bytes(magic, 8);
  if (std::memcmp(magic, kMagic, 8) != 0) throw DataError(path, "not a tinbuild constraint file");
  PreparedConstraints c;
  c.spacing = in.get<double>();
  c.buffer = in.get<double>();
  c.shoreDistance = in.get<double>();
  c.stationSpacing = in.get<double>();
  c.breaklines = in.get<std::uint64_t>();
  auto cc = std::make_shared<ConformingConstraints>();
  const std::uint64_t nv = in.get<std::uint64_t>();
  if (nv > (std::uint64_t{1} << 31)) throw DataError(path, "corrupt constraint file");
  in.need(nv * 24);
  cc->vertices.resize(nv);
  for (auto& p : cc->vertices) {
    p.x = in.get<double>();
    p.y = in.get<double>();
    p.z = in.get<double>();
  }
  const std::uint64_t np = in.get<std::uint64_t>();
  if (np > (std::uint64_t{1} << 32)) throw DataError(path, "corrupt constraint file");
  in.need(np * 8);
  cc->pieces.resize(np);
  for (auto& p : cc->pieces) {
    p[0] = in.get<std::uint32_t>();
    p[1] = in.get<std::uint32_t>();
    if (p[0] >= nv || p[1] >= nv) throw DataError(path, "corrupt constraint file (a piece's vertex)");
  }
  auto ring = [&in, &path]() {
    const std::uint64_t n = in.get<std::uint64_t>();
    if (n > (std::uint64_t{1} << 31)) throw DataError(path, "corrupt constraint file");
    in.need(n * 16);
    std::vector<std::array<double, 2>> r(n);
    for (auto& q : r) {
      q[0] = in.get<double>();
      q[1] = in.get<double>();
    }
    return r;
  };
  const std::uint64_t nw = in.get<std::uint64_t>();
  if (nw > (std::uint64_t{1} << 24)) throw DataError(path, "corrupt constraint file");
  for (std::uint64_t i = 0; i < nw; ++i) {
    WaterArea w;
    w.outer = ring();
    const std::uint64_t nh = in.get<std::uint64_t>();
    if (nh > (std::uint64_t{1} << 24)) throw DataError(path, "corrupt constraint file");
    for (std::uint64_t h = 0; h < nh; ++h) w.holes.push_back(ring());
    c.water.push_back(std::move(w));
  }
  const std::uint64_t nb = in.get<std::uint64_t>();
  if (nb > (std::uint64_t{1} << 24)) throw DataError(path, "corrupt constraint file");
  for (std::uint64_t i = 0; i < nb; ++i) {
    WaterBody b;
    const std::uint64_t len = in.get<std::uint64_t>();
    if (len > 65536) throw DataError(path, "corrupt constraint file");
    b.source.resize(len);
    in.bytes(b.source.data(), len);
    const std::uint64_t flags = in.get<std::uint64_t>();
    b.river = flags & 1;
    b.given = flags & 2;
    b.level = in.get<double>();
    b.lastLevel = in.get<double>();
    b.bankPoints = in.get<std::uint64_t>();
    b.stations = static_cast<std::uint32_t>(in.get<std::uint64_t>());
    b.body = in.get<std::uint64_t>();
    b.members = in.get<std::uint64_t>();
    b.area = in.get<std::uint64_t>();
    b.outliers = in.get<std::uint64_t>();
    if (b.body >= nb || b.area >= nw) throw DataError(path, "corrupt constraint file (a water body)");
    if (in.get<std::uint64_t>()) {
      auto p = std::make_shared<RiverProfile>();
      p->centreline = ring();
      p->s0 = in.get<double>();
      p->step = in.get<double>();
      p->sections = static_cast<std::uint32_t>(in.get<std::uint64_t>());
      const std::uint64_t ns = in.get<std::uint64_t>();
      if (ns > (std::uint64_t{1} << 28)) throw DataError(path, "corrupt constraint file");
      in.need(ns * 24);
      for (std::uint64_t k = 0; k < ns; ++k) {
        p->raw.push_back(in.get<double>());
        p->level.push_back(in.get<double>());
        p->points.push_back(static_cast<std::uint32_t>(in.get<std::uint64_t>()));
      }
      b.profile = std::move(p);
    }
    c.bodies.push_back(b);
  }
  const std::uint64_t no = in.get<std::uint64_t>();
  if (no > (std::uint64_t{1} << 31)) throw DataError(path, "corrupt constraint file");
  in.need(no * 24);
  c.outliers.resize(no);
  for (auto& p : c.outliers) {
    p.x = in.get<double>();
    p.y = in.get<double>();
    p.z = in.get<double>();
  }
  c.band = in.get<double>();
  in.bytes(magic, 8);
  if (std::memcmp(magic, kMagic, 8) != 0) throw DataError(path, "corrupt constraint file (its end)");
  cc->stats.vertices = cc->vertices.size();
  cc->stats.pieces = cc->pieces.size();
  c.conforming = std::move(cc);
  return c;
}

}  // namespace tinbuild
