#include "engine/ray_cast_wide.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define SLAM_WIDE_WINDOW_KERNELS 1
#include <immintrin.h>
#endif

// The wide kernels of CastToObstacles(MatchWindow, ...): FastRay<WindowField>'s traversal
// (fast_ray.hpp) on four or eight rays per instruction. Every operation is the scalar one on
// each lane (IEEE double arithmetic, without contraction: the engine is built with
// -ffp-contract=off), so every answer is the portable kernel's, bit for bit.

namespace slam::wide {

#ifdef SLAM_WIDE_WINDOW_KERNELS

namespace {

/// The window's rays, started as FastRay starts them, one array per quantity (eight
/// consecutive rays' values are loaded at once); reused per thread.
struct WideRays {
  std::vector<double> px, py, dx, dy, range;  // the queries, one array per quantity
  std::vector<double> ox, oy, ax, ay, ix, iy, length, max_range;
  std::vector<int32_t> base, step_u, step_v;
  std::vector<uint32_t> index;      // in the caller's rays
  std::vector<uint32_t> uncovered;  // the caller's rays the window does not cover
  // The answers, in the order the rays finish: which ray (in these arrays), and what it found.
  std::vector<int32_t> finished, hit, cells, jumps;
  std::vector<double> distance, exit;

  /// Room for n rays and the eight lanes' reads past them (grows only: no refill of zeros).
  void Reserve(size_t n) {
    if (index.size() >= n + 8) return;
    for (auto* v : {&px, &py, &dx, &dy, &range, &ox, &oy, &ax, &ay, &ix, &iy, &length, &max_range,
                    &distance, &exit}) {
      v->resize(n + 8);
    }
    for (auto* v : {&base, &step_u, &step_v, &finished, &hit, &cells, &jumps}) v->resize(n + 8);
    for (auto* v : {&index, &uncovered}) v->resize(n + 8);
  }
};

/// The queries one array per quantity (plain loads and stores, done with before a kernel's
/// vector loads read them: gathering them from the RayQuery vector cost as much as the rays).
void CopyQueries(const std::vector<RayQuery>& rays, WideRays& in) {
  for (size_t i = 0; i < rays.size(); ++i) {
    const RayQuery& q = rays[i];
    in.px[i] = q.origin.x();
    in.py[i] = q.origin.y();
    in.dx[i] = q.direction.x();
    in.dy[i] = q.direction.y();
    in.range[i] = q.max_range_m;
  }
}

/// What a wide kernel leaves to others: the rays the window does not cover, through the grid;
/// and the covered rays' answers, packed in finishing order, put in place.
void FinishWindowRays(const MatchWindow& window, const std::vector<RayQuery>& rays,
                      const WideRays& in, size_t covered, size_t uncovered,
                      std::vector<RayHit>& hits) {
  for (size_t j = 0; j < uncovered; ++j) {
    const RayQuery& q = rays[in.uncovered[j]];
    hits[in.uncovered[j]] = CastToObstacle(window.grid(), q.origin, q.direction, q.max_range_m,
                                           window.occupied_above());
  }
  for (size_t j = 0; j < covered; ++j) {
    const auto r = static_cast<size_t>(in.finished[j]);
    RayHit& h = hits[in.index[r]];
    h.hit = in.hit[j] != 0;
    h.distance_m = h.hit ? in.distance[j] : in.max_range[r];
    h.exit_m = h.hit ? in.exit[j] : in.max_range[r];
    h.cells = in.cells[j];
    h.jumps = in.jumps[j];
  }
}

#define SLAM_WIDE_TARGET __attribute__((target("avx2,bmi2,avx512f,avx512vl")))
#define SLAM_WIDE_INLINE __attribute__((target("avx2,bmi2,avx512f,avx512vl"), always_inline)) inline
// GCC 12's AVX-512 headers start some results from _mm512_undefined_pd(), a variable initialised
// from itself, which -Wmaybe-uninitialized reports once inlined here (a known false positive).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

/// The `n` lowest set bits of `mask`.
SLAM_WIDE_INLINE __mmask8 LowestBits(__mmask8 mask, int n) {
  return static_cast<__mmask8>(_pdep_u32((1u << std::min(n, 8)) - 1, mask));
}

/// FloorToInt on each lane (a truncation, one less where that rounded up).
SLAM_WIDE_TARGET inline __m256i FloorLanes(__m512d g) {
  const __m256i truncated = _mm512_cvttpd_epi32(g);
  const __mmask8 below = _mm512_cmp_pd_mask(g, _mm512_cvtepi32_pd(truncated), _CMP_LT_OQ);
  return _mm256_mask_sub_epi32(truncated, below, truncated, _mm256_set1_epi32(1));
}

/// -g on the lanes of `where` (the sign bit flipped, as the scalar negation does).
SLAM_WIDE_TARGET inline __m512d NegateLanes(__m512d g, __mmask8 where) {
  const __m512i bits = _mm512_castpd_si512(g);
  return _mm512_castsi512_pd(
      _mm512_mask_xor_epi64(bits, where, bits, _mm512_set1_epi64(INT64_MIN)));
}

/// What every lane's step reads.
struct WideStep {
  const uint8_t* squares;  // the window's free squares
  __m512d res;             // the grid's resolution
};

/// Eight lanes, each advancing one ray as FastRay<WindowField> does, and taking the next ray
/// as soon as its own has its answer. Every operation is the scalar one on each lane (IEEE
/// double arithmetic without contraction, the same comparisons, std::min(a, b) as min(b, a),
/// which keeps the scalar choice for equal values and NaN), so each answer is FastRay's, bit
/// for bit.
struct WideLanes {
  __m512d ox, oy, ax, ay, ix, iy, length, t;
  __m256i base, step_u, step_v, u, v, cells, jumps, ray;
  __mmask8 active = 0, free_lanes = 0xff;

  SLAM_WIDE_INLINE WideLanes() {
    ox = oy = ax = ay = ix = iy = length = t = _mm512_setzero_pd();
    base = step_u = step_v = u = v = cells = jumps = ray = _mm256_setzero_si256();
  }

  /// Lanes without a ray take the next ones (consecutive in `in`, expanded into the lanes).
  SLAM_WIDE_INLINE void Fill(const WideRays& in, int32_t& next, int32_t count) {
    if (free_lanes == 0 || next >= count) return;
    const __mmask8 fill = LowestBits(free_lanes, count - next);
    free_lanes = static_cast<__mmask8>(free_lanes & ~fill);
    ox = _mm512_mask_expand_pd(ox, fill, _mm512_loadu_pd(in.ox.data() + next));
    oy = _mm512_mask_expand_pd(oy, fill, _mm512_loadu_pd(in.oy.data() + next));
    ax = _mm512_mask_expand_pd(ax, fill, _mm512_loadu_pd(in.ax.data() + next));
    ay = _mm512_mask_expand_pd(ay, fill, _mm512_loadu_pd(in.ay.data() + next));
    ix = _mm512_mask_expand_pd(ix, fill, _mm512_loadu_pd(in.ix.data() + next));
    iy = _mm512_mask_expand_pd(iy, fill, _mm512_loadu_pd(in.iy.data() + next));
    length = _mm512_mask_expand_pd(length, fill, _mm512_loadu_pd(in.length.data() + next));
    base = _mm256_mask_expand_epi32(
        base, fill, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.base.data() + next)));
    step_u = _mm256_mask_expand_epi32(
        step_u, fill,
        _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.step_u.data() + next)));
    step_v = _mm256_mask_expand_epi32(
        step_v, fill,
        _mm256_loadu_si256(reinterpret_cast<const __m256i*>(in.step_v.data() + next)));
    ray = _mm256_mask_expand_epi32(
        ray, fill,
        _mm256_add_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32(next)));
    const __m256i zero_i = _mm256_setzero_si256();
    t = _mm512_mask_mov_pd(t, fill, _mm512_setzero_pd());
    u = _mm256_mask_mov_epi32(u, fill, zero_i);
    v = _mm256_mask_mov_epi32(v, fill, zero_i);
    cells = _mm256_mask_mov_epi32(cells, fill, zero_i);
    jumps = _mm256_mask_mov_epi32(jumps, fill, zero_i);
    active = static_cast<__mmask8>(active | fill);
    next += _mm_popcnt_u32(fill);
  }

  /// One jump or one cell of every active lane; the finished lanes' answers packed into
  /// `answers`' arrays from `finished` on.
  SLAM_WIDE_INLINE void Advance(const WideStep& step, WideRays& answers, int32_t& finished) {
    if (active == 0) return;
    const __m512d one = _mm512_set1_pd(1.0);
    const __m256i zero_i = _mm256_setzero_si256(), one_i = _mm256_set1_epi32(1);
    // WindowField::At: the free square of the ray's quadrant at its cell (a 4-byte load at
    // each byte's address, the padding after the squares keeps it inside).
    const __m256i at = _mm256_add_epi32(
        base, _mm256_add_epi32(_mm256_mullo_epi32(step_u, u), _mm256_mullo_epi32(step_v, v)));
    const __m256i k = _mm256_and_si256(
        _mm256_mmask_i32gather_epi32(zero_i, active, at, step.squares, 1), _mm256_set1_epi32(0xff));
    const __mmask8 occupied = _mm256_cmpeq_epi32_mask(k, zero_i);
    // A hit, unless the ray only touches the cell.
    const __m512d leave_u =
        _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(_mm256_add_epi32(u, one_i)), ox), ix);
    const __m512d leave_v =
        _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(_mm256_add_epi32(v, one_i)), oy), iy);
    const __m512d t_leave = _mm512_min_pd(length, _mm512_min_pd(leave_v, leave_u));
    const __mmask8 hit =
        static_cast<__mmask8>(occupied & _mm512_cmp_pd_mask(t_leave, t, _CMP_GT_OQ));
    // LeaveBox: out of the free square (of this cell when k <= 1).
    const __m256i reach = _mm256_max_epi32(k, one_i);
    const __m256i end_u = _mm256_add_epi32(u, reach), end_v = _mm256_add_epi32(v, reach);
    const __mmask8 jump = _mm256_cmpgt_epi32_mask(k, one_i);
    const __m512d exit_u = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(end_u), ox), ix);
    const __m512d exit_v = _mm512_mul_pd(_mm512_sub_pd(_mm512_cvtepi32_pd(end_v), oy), iy);
    const __m512d t_exit = _mm512_min_pd(exit_v, exit_u);
    const auto counted = static_cast<__mmask8>(active & ~hit);
    jumps = _mm256_mask_add_epi32(jumps, static_cast<__mmask8>(counted & jump), jumps, one_i);
    const __mmask8 crossed = _mm512_cmp_pd_mask(_mm512_min_pd(length, t_exit), t, _CMP_GT_OQ);
    cells = _mm256_mask_add_epi32(cells, static_cast<__mmask8>(counted & ~jump & crossed), cells,
                                  one_i);
    const __mmask8 out = _mm512_cmp_pd_mask(t_exit, length, _CMP_GE_OQ);
    const __m512d slack =
        _mm512_mul_pd(_mm512_set1_pd(GridWalk::kCornerEpsilon), _mm512_add_pd(one, t_exit));
    const __mmask8 corner =
        _mm512_cmp_pd_mask(_mm512_abs_pd(_mm512_sub_pd(exit_u, exit_v)), slack, _CMP_LE_OQ);
    const __m512d ahead = _mm512_add_pd(t_exit, slack);
    const __m256i along_u = _mm256_min_epi32(
        _mm256_max_epi32(_mm512_cvttpd_epi32(_mm512_add_pd(ox, _mm512_mul_pd(ax, ahead))), u),
        _mm256_sub_epi32(end_u, one_i));
    const __m256i along_v = _mm256_min_epi32(
        _mm256_max_epi32(_mm512_cvttpd_epi32(_mm512_add_pd(oy, _mm512_mul_pd(ay, ahead))), v),
        _mm256_sub_epi32(end_v, one_i));
    const auto across_u =
        static_cast<__mmask8>(corner | _mm512_cmp_pd_mask(exit_u, exit_v, _CMP_LT_OQ));
    const auto across_v =
        static_cast<__mmask8>(corner | _mm512_cmp_pd_mask(exit_v, exit_u, _CMP_LT_OQ));
    const __m512d t_hit = t;
    u = _mm256_mask_blend_epi32(across_u, along_u, end_u);
    v = _mm256_mask_blend_epi32(across_v, along_v, end_v);
    t = _mm512_max_pd(t_exit, t);

    const auto done = static_cast<__mmask8>(active & (hit | out));
    if (done == 0) return;
    // The finished lanes' answers, packed, then their lanes are free for the next rays.
    const auto at_out = static_cast<size_t>(finished);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.finished.data() + at_out),
                        _mm256_maskz_compress_epi32(done, ray));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.hit.data() + at_out),
                        _mm256_maskz_compress_epi32(done, _mm256_maskz_mov_epi32(hit, one_i)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.cells.data() + at_out),
                        _mm256_maskz_compress_epi32(done, cells));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(answers.jumps.data() + at_out),
                        _mm256_maskz_compress_epi32(done, jumps));
    _mm512_storeu_pd(answers.distance.data() + at_out,
                     _mm512_maskz_compress_pd(done, _mm512_mul_pd(t_hit, step.res)));
    _mm512_storeu_pd(answers.exit.data() + at_out,
                     _mm512_maskz_compress_pd(done, _mm512_mul_pd(t_leave, step.res)));
    finished += _mm_popcnt_u32(done);
    active = static_cast<__mmask8>(active & ~done);
    free_lanes = static_cast<__mmask8>(free_lanes | done);
  }
};

/// CastToObstacles(window, rays, hits) eight rays at a time: rays start eight at a time
/// (MatchWindow::Covers and FastRay's constructor on each lane, the same operations), the
/// covered ones are packed, then advance in WideLanes.
SLAM_WIDE_TARGET void CastEight(const MatchWindow& window, const std::vector<RayQuery>& rays,
                                std::vector<RayHit>& hits) {
  const GridGeometry& geometry = window.grid().geometry();
  const size_t n = rays.size();
  hits.resize(n);
  thread_local WideRays in;
  in.Reserve(n);

  const __m512d zero = _mm512_setzero_pd(), one = _mm512_set1_pd(1.0);
  const __m256i zero_i = _mm256_setzero_si256(), one_i = _mm256_set1_epi32(1);
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);

  // Starting the rays: the queries one array per quantity, then eight at a time.
  CopyQueries(rays, in);
  const __m512d inv = _mm512_set1_pd(1.0 / geometry.resolution());
  const __m512d res = _mm512_set1_pd(geometry.resolution());
  const std::array<double, 4> box = window.CoverBox();
  const CellIndex lo = window.lo();
  const __m512d x_min = _mm512_set1_pd(box[0]), y_min = _mm512_set1_pd(box[1]);
  const __m512d x_max = _mm512_set1_pd(box[2]), y_max = _mm512_set1_pd(box[3]);
  const __m512d infinity = _mm512_set1_pd(std::numeric_limits<double>::infinity());
  const __m256i width = _mm256_set1_epi32(static_cast<int32_t>(window.width()));
  const __m256i cells_per_quadrant = _mm256_set1_epi32(static_cast<int32_t>(window.cells()));
  const __m256i x0 = _mm256_set1_epi32(lo.x), y0 = _mm256_set1_epi32(lo.y);
  size_t covered = 0, uncovered = 0;
  for (size_t i = 0; i < n; i += 8) {
    const auto lanes = static_cast<__mmask8>(n - i >= 8 ? 0xff : (1u << (n - i)) - 1);
    const __m512d px = _mm512_maskz_loadu_pd(lanes, in.px.data() + i),
                  py = _mm512_maskz_loadu_pd(lanes, in.py.data() + i);
    const __m512d dx = _mm512_maskz_loadu_pd(lanes, in.dx.data() + i),
                  dy = _mm512_maskz_loadu_pd(lanes, in.dy.data() + i);
    const __m512d range = _mm512_maskz_loadu_pd(lanes, in.range.data() + i);
    // MatchWindow::Covers: a positive, finite range, both ends inside the window's margin.
    const __m512d gx = _mm512_mul_pd(px, inv), gy = _mm512_mul_pd(py, inv);
    const __m512d ex = _mm512_mul_pd(_mm512_add_pd(px, _mm512_mul_pd(dx, range)), inv);
    const __m512d ey = _mm512_mul_pd(_mm512_add_pd(py, _mm512_mul_pd(dy, range)), inv);
    __mmask8 inside = static_cast<__mmask8>(lanes & _mm512_cmp_pd_mask(range, zero, _CMP_GT_OQ) &
                                            _mm512_cmp_pd_mask(range, infinity, _CMP_LT_OQ));
    inside = static_cast<__mmask8>(inside & _mm512_cmp_pd_mask(gx, x_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(gx, x_max, _CMP_LE_OQ) &
                                   _mm512_cmp_pd_mask(ex, x_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(ex, x_max, _CMP_LE_OQ));
    inside = static_cast<__mmask8>(inside & _mm512_cmp_pd_mask(gy, y_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(gy, y_max, _CMP_LE_OQ) &
                                   _mm512_cmp_pd_mask(ey, y_min, _CMP_GE_OQ) &
                                   _mm512_cmp_pd_mask(ey, y_max, _CMP_LE_OQ));
    const __m256i ray = _mm256_add_epi32(lane, _mm256_set1_epi32(static_cast<int32_t>(i)));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.uncovered.data() + uncovered),
                        _mm256_maskz_compress_epi32(static_cast<__mmask8>(lanes & ~inside), ray));
    uncovered += static_cast<size_t>(_mm_popcnt_u32(static_cast<__mmask8>(lanes & ~inside)));
    if (inside == 0) continue;
    // FastRay's constructor: the first cell (FloorToInt), mirrored where the ray goes back.
    const __mmask8 back_x = _mm512_cmp_pd_mask(dx, zero, _CMP_LT_OQ),
                   back_y = _mm512_cmp_pd_mask(dy, zero, _CMP_LT_OQ);
    const __m256i cx = FloorLanes(gx), cy = FloorLanes(gy);
    const __m256i all_ones = _mm256_set1_epi32(-1);
    const __m256i u0 = _mm256_mask_xor_epi32(cx, back_x, cx, all_ones);
    const __m256i v0 = _mm256_mask_xor_epi32(cy, back_y, cy, all_ones);
    const __m512d ox = _mm512_sub_pd(NegateLanes(gx, back_x), _mm512_cvtepi32_pd(u0));
    const __m512d oy = _mm512_sub_pd(NegateLanes(gy, back_y), _mm512_cvtepi32_pd(v0));
    const __m512d ax = _mm512_abs_pd(dx), ay = _mm512_abs_pd(dy);
    // WindowField::CursorFor: the first cell in the ray's quadrant, and how far steps move.
    const __m256i quadrant = _mm256_add_epi32(_mm256_maskz_mov_epi32(back_x, one_i),
                                              _mm256_maskz_mov_epi32(back_y, _mm256_set1_epi32(2)));
    const __m256i base =
        _mm256_add_epi32(_mm256_mullo_epi32(quadrant, cells_per_quadrant),
                         _mm256_add_epi32(_mm256_mullo_epi32(_mm256_sub_epi32(cy, y0), width),
                                          _mm256_sub_epi32(cx, x0)));
    const __m256i step_u = _mm256_mask_sub_epi32(one_i, back_x, zero_i, one_i);
    const __m256i step_v = _mm256_mask_sub_epi32(width, back_y, zero_i, width);
    // Packed: the covered lanes' values one after another.
    _mm512_storeu_pd(in.ox.data() + covered, _mm512_maskz_compress_pd(inside, ox));
    _mm512_storeu_pd(in.oy.data() + covered, _mm512_maskz_compress_pd(inside, oy));
    _mm512_storeu_pd(in.ax.data() + covered, _mm512_maskz_compress_pd(inside, ax));
    _mm512_storeu_pd(in.ay.data() + covered, _mm512_maskz_compress_pd(inside, ay));
    _mm512_storeu_pd(in.ix.data() + covered,
                     _mm512_maskz_compress_pd(inside, _mm512_div_pd(one, ax)));
    _mm512_storeu_pd(in.iy.data() + covered,
                     _mm512_maskz_compress_pd(inside, _mm512_div_pd(one, ay)));
    _mm512_storeu_pd(in.length.data() + covered,
                     _mm512_maskz_compress_pd(inside, _mm512_div_pd(range, res)));
    _mm512_storeu_pd(in.max_range.data() + covered, _mm512_maskz_compress_pd(inside, range));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.base.data() + covered),
                        _mm256_maskz_compress_epi32(inside, base));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.step_u.data() + covered),
                        _mm256_maskz_compress_epi32(inside, step_u));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.step_v.data() + covered),
                        _mm256_maskz_compress_epi32(inside, step_v));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(in.index.data() + covered),
                        _mm256_maskz_compress_epi32(inside, ray));
    covered += static_cast<size_t>(_mm_popcnt_u32(inside));
  }

  // Advancing them (one group of eight lanes: two groups side by side are slower).
  const WideStep step{window.free_squares(), res};
  WideLanes lanes;
  const auto count = static_cast<int32_t>(covered);
  int32_t next = 0, finished = 0;
  while (true) {
    lanes.Fill(in, next, count);
    if (lanes.active == 0) break;
    lanes.Advance(step, in, finished);
  }
  FinishWindowRays(window, rays, in, covered, uncovered, hits);
}

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
#undef SLAM_WIDE_INLINE
#undef SLAM_WIDE_TARGET

// The AVX2 kernel: WideLanes' plan on four lanes, with vector masks where AVX-512 has mask
// registers, and tables where it has compress and expand.
#define SLAM_AVX2_TARGET __attribute__((target("avx2")))
#define SLAM_AVX2_INLINE __attribute__((target("avx2"), always_inline)) inline

/// For each set of four lanes (bit j: lane j): the lanes as masks of 64-bit and 32-bit lanes,
/// and permutations (of 32-bit elements, _mm256_permutevar8x32) that expand consecutive values
/// into those lanes (lane j takes the value of its rank among them) or compress those lanes'
/// values into consecutive ones, for doubles (two elements a value) and 32-bit integers.
struct FourLanes {
  int64_t mask64[16][4];
  int32_t mask32[16][4];
  int32_t expand64[16][8], expand32[16][8], compress64[16][8], compress32[16][8];
};

constexpr FourLanes MakeFourLanes() {
  FourLanes t{};
  for (int m = 0; m < 16; ++m) {
    int rank = 0;
    for (int j = 0; j < 4; ++j) {
      const bool in = ((m >> j) & 1) != 0;
      t.mask64[m][j] = in ? -1 : 0;
      t.mask32[m][j] = in ? -1 : 0;
      const int from = in ? rank : j;  // lanes outside the set are blended away
      t.expand64[m][2 * j] = 2 * from;
      t.expand64[m][2 * j + 1] = 2 * from + 1;
      t.expand32[m][j] = from;
      t.expand32[m][j + 4] = j + 4;
      if (in) {
        t.compress64[m][2 * rank] = 2 * j;
        t.compress64[m][2 * rank + 1] = 2 * j + 1;
        t.compress32[m][rank] = j;
        ++rank;
      }
    }
    for (int k = rank; k < 4; ++k) {
      t.compress64[m][2 * k] = 2 * k;
      t.compress64[m][2 * k + 1] = 2 * k + 1;
      t.compress32[m][k] = k;
    }
    for (int k = 4; k < 8; ++k) t.compress32[m][k] = k;
  }
  return t;
}

alignas(64) constexpr FourLanes kFourLanes = MakeFourLanes();

SLAM_AVX2_INLINE __m256i Row8(const int32_t (&row)[8]) {
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row));
}
SLAM_AVX2_INLINE __m256d Mask64(unsigned lanes) {
  return _mm256_castsi256_pd(
      _mm256_loadu_si256(reinterpret_cast<const __m256i*>(kFourLanes.mask64[lanes])));
}
SLAM_AVX2_INLINE __m128i Mask32(unsigned lanes) {
  return _mm_loadu_si128(reinterpret_cast<const __m128i*>(kFourLanes.mask32[lanes]));
}
SLAM_AVX2_INLINE __m128i Load32(const int32_t* p) {
  return _mm_loadu_si128(reinterpret_cast<const __m128i*>(p));
}
SLAM_AVX2_INLINE void Store32(int32_t* p, __m128i value) {
  _mm_storeu_si128(reinterpret_cast<__m128i*>(p), value);
}
/// The lanes of a mask of 64-bit lanes as bits.
SLAM_AVX2_INLINE unsigned Bits(__m256d mask) {
  return static_cast<unsigned>(_mm256_movemask_pd(mask));
}
SLAM_AVX2_INLINE __m256d PermutePd(__m256d v, __m256i order) {
  return _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(v), order));
}
SLAM_AVX2_INLINE __m128i PermuteEpi32(__m128i v, __m256i order) {
  return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_castsi128_si256(v), order));
}
/// A mask of 64-bit lanes as a mask of 32-bit lanes (each lane's low half: all ones or zero).
SLAM_AVX2_INLINE __m128i Narrow(__m256d mask) {
  return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(
      _mm256_castpd_si256(mask), _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)));
}
/// A mask of 32-bit lanes as a mask of 64-bit lanes.
SLAM_AVX2_INLINE __m256d Widen(__m128i mask) {
  return _mm256_castsi256_pd(_mm256_cvtepi32_epi64(mask));
}

/// The AVX2 kernel's start, four rays at a time: MatchWindow::Covers and FastRay's start on
/// each lane (the same operations), the covered rays packed into `in`, the others listed in
/// in.uncovered. Returns how many rays are covered.
SLAM_AVX2_TARGET size_t StartAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays,
                                  WideRays& in, size_t& uncovered) {
  const GridGeometry& geometry = window.grid().geometry();
  const size_t n = rays.size();
  CopyQueries(rays, in);
  const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0), sign = _mm256_set1_pd(-0.0);
  const __m128i one_i = _mm_set1_epi32(1);
  const __m256d inv = _mm256_set1_pd(1.0 / geometry.resolution()),
                res = _mm256_set1_pd(geometry.resolution());
  const std::array<double, 4> box = window.CoverBox();
  const CellIndex lo = window.lo();
  const __m256d x_min = _mm256_set1_pd(box[0]), y_min = _mm256_set1_pd(box[1]);
  const __m256d x_max = _mm256_set1_pd(box[2]), y_max = _mm256_set1_pd(box[3]);
  const __m256d infinity = _mm256_set1_pd(std::numeric_limits<double>::infinity());
  const __m128i width = _mm_set1_epi32(static_cast<int32_t>(window.width()));
  const __m128i cells_per_quadrant = _mm_set1_epi32(static_cast<int32_t>(window.cells()));
  const __m128i x0 = _mm_set1_epi32(lo.x), y0 = _mm_set1_epi32(lo.y);
  size_t covered = 0;
  uncovered = 0;
  for (size_t i = 0; i < n; i += 4) {
    const unsigned lanes =
        n - i >= 4 ? 0xfu : (1u << (n - i)) - 1;  // past n: stale values, never used
    const __m256d px = _mm256_loadu_pd(in.px.data() + i), py = _mm256_loadu_pd(in.py.data() + i);
    const __m256d dx = _mm256_loadu_pd(in.dx.data() + i), dy = _mm256_loadu_pd(in.dy.data() + i);
    const __m256d range = _mm256_loadu_pd(in.range.data() + i);
    // MatchWindow::Covers: a positive, finite range, both ends inside the window's margin.
    const __m256d gx = _mm256_mul_pd(px, inv), gy = _mm256_mul_pd(py, inv);
    const __m256d ex = _mm256_mul_pd(_mm256_add_pd(px, _mm256_mul_pd(dx, range)), inv);
    const __m256d ey = _mm256_mul_pd(_mm256_add_pd(py, _mm256_mul_pd(dy, range)), inv);
    __m256d inside = _mm256_and_pd(_mm256_cmp_pd(range, zero, _CMP_GT_OQ),
                                   _mm256_cmp_pd(range, infinity, _CMP_LT_OQ));
    for (const __m256d* g : {&gx, &ex}) {
      inside = _mm256_and_pd(inside, _mm256_and_pd(_mm256_cmp_pd(*g, x_min, _CMP_GE_OQ),
                                                   _mm256_cmp_pd(*g, x_max, _CMP_LE_OQ)));
    }
    for (const __m256d* g : {&gy, &ey}) {
      inside = _mm256_and_pd(inside, _mm256_and_pd(_mm256_cmp_pd(*g, y_min, _CMP_GE_OQ),
                                                   _mm256_cmp_pd(*g, y_max, _CMP_LE_OQ)));
    }
    const unsigned in_bits = lanes & Bits(inside), out_bits = lanes & ~in_bits;
    const __m128i ray =
        _mm_add_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_set1_epi32(static_cast<int32_t>(i)));
    Store32(reinterpret_cast<int32_t*>(in.uncovered.data() + uncovered),
            PermuteEpi32(ray, Row8(kFourLanes.compress32[out_bits])));
    uncovered += static_cast<size_t>(__builtin_popcount(out_bits));
    if (in_bits == 0) continue;
    // FastRay's constructor: the first cell (FloorToInt), mirrored where the ray goes back.
    const __m256d back_x = _mm256_cmp_pd(dx, zero, _CMP_LT_OQ),
                  back_y = _mm256_cmp_pd(dy, zero, _CMP_LT_OQ);
    const __m128i back_x32 = Narrow(back_x), back_y32 = Narrow(back_y);
    const auto floor = [](__m256d g) SLAM_AVX2_TARGET {
      const __m128i truncated = _mm256_cvttpd_epi32(g);
      return _mm_add_epi32(truncated,
                           Narrow(_mm256_cmp_pd(g, _mm256_cvtepi32_pd(truncated), _CMP_LT_OQ)));
    };
    const __m128i cx = floor(gx), cy = floor(gy);
    const __m128i u0 = _mm_xor_si128(cx, back_x32), v0 = _mm_xor_si128(cy, back_y32);
    const __m256d ox =
        _mm256_sub_pd(_mm256_xor_pd(gx, _mm256_and_pd(back_x, sign)), _mm256_cvtepi32_pd(u0));
    const __m256d oy =
        _mm256_sub_pd(_mm256_xor_pd(gy, _mm256_and_pd(back_y, sign)), _mm256_cvtepi32_pd(v0));
    const __m256d ax = _mm256_andnot_pd(sign, dx), ay = _mm256_andnot_pd(sign, dy);
    // WindowField::CursorFor.
    const __m128i quadrant =
        _mm_add_epi32(_mm_and_si128(back_x32, one_i), _mm_and_si128(back_y32, _mm_set1_epi32(2)));
    const __m128i base = _mm_add_epi32(
        _mm_mullo_epi32(quadrant, cells_per_quadrant),
        _mm_add_epi32(_mm_mullo_epi32(_mm_sub_epi32(cy, y0), width), _mm_sub_epi32(cx, x0)));
    const __m128i step_u = _mm_or_si128(back_x32, one_i);  // -1 or 1
    const __m128i step_v =
        _mm_sub_epi32(_mm_xor_si128(width, back_y32), back_y32);  // -width or width
    // Packed: the covered lanes' values one after another.
    const __m256i c64 = Row8(kFourLanes.compress64[in_bits]),
                  c32 = Row8(kFourLanes.compress32[in_bits]);
    const auto pack = [&](std::vector<double>& out, __m256d value) SLAM_AVX2_TARGET {
      _mm256_storeu_pd(out.data() + covered, PermutePd(value, c64));
    };
    pack(in.ox, ox);
    pack(in.oy, oy);
    pack(in.ax, ax);
    pack(in.ay, ay);
    pack(in.ix, _mm256_div_pd(one, ax));
    pack(in.iy, _mm256_div_pd(one, ay));
    pack(in.length, _mm256_div_pd(range, res));
    pack(in.max_range, range);
    Store32(in.base.data() + covered, PermuteEpi32(base, c32));
    Store32(in.step_u.data() + covered, PermuteEpi32(step_u, c32));
    Store32(in.step_v.data() + covered, PermuteEpi32(step_v, c32));
    Store32(reinterpret_cast<int32_t*>(in.index.data() + covered), PermuteEpi32(ray, c32));
    covered += static_cast<size_t>(__builtin_popcount(in_bits));
  }
  return covered;
}

/// Four lanes, each advancing one ray as FastRay<WindowField> does (see WideLanes: the same
/// operations on each lane, so the same answers bit for bit).
struct Avx2Lanes {
  // Sixteen vector registers for the state and the step's temporaries: pairs of 32-bit
  // quantities share one register (u in the low half, v in the high one; the steps alike; cells
  // in the low 16 bits of `counts`, jumps in the high ones: a window's ray crosses far fewer
  // than 65 536 cells), or the lanes' state spills to the stack, which is slower.
  __m256d ox, oy, ax, ay, ix, iy, length, t;
  __m256i uv, steps;
  __m128i base, counts, ray;
  unsigned active = 0, free_lanes = 0xf;

  SLAM_AVX2_INLINE Avx2Lanes() {
    ox = oy = ax = ay = ix = iy = length = t = _mm256_setzero_pd();
    uv = steps = _mm256_setzero_si256();
    base = counts = ray = _mm_setzero_si128();
  }

  /// Lanes without a ray take the next ones (consecutive in `in`, expanded into the lanes).
  SLAM_AVX2_INLINE void Fill(const WideRays& in, int32_t& next, int32_t count) {
    if (free_lanes == 0 || next >= count) return;
    unsigned fill = free_lanes;
    while (__builtin_popcount(fill) > count - next)
      fill &= ~(1u << (31 - __builtin_clz(fill)));  // keep the lowest
    free_lanes &= ~fill;
    const __m256i e64 = Row8(kFourLanes.expand64[fill]), e32 = Row8(kFourLanes.expand32[fill]);
    const __m256d m64 = Mask64(fill);
    const __m128i m32 = Mask32(fill);
    const __m256i m32_both = _mm256_set_m128i(m32, m32);
    const auto n = static_cast<size_t>(next);
    ox = _mm256_blendv_pd(ox, PermutePd(_mm256_loadu_pd(in.ox.data() + n), e64), m64);
    oy = _mm256_blendv_pd(oy, PermutePd(_mm256_loadu_pd(in.oy.data() + n), e64), m64);
    ax = _mm256_blendv_pd(ax, PermutePd(_mm256_loadu_pd(in.ax.data() + n), e64), m64);
    ay = _mm256_blendv_pd(ay, PermutePd(_mm256_loadu_pd(in.ay.data() + n), e64), m64);
    ix = _mm256_blendv_pd(ix, PermutePd(_mm256_loadu_pd(in.ix.data() + n), e64), m64);
    iy = _mm256_blendv_pd(iy, PermutePd(_mm256_loadu_pd(in.iy.data() + n), e64), m64);
    length = _mm256_blendv_pd(length, PermutePd(_mm256_loadu_pd(in.length.data() + n), e64), m64);
    t = _mm256_andnot_pd(m64, t);
    base = _mm_blendv_epi8(base, PermuteEpi32(Load32(in.base.data() + n), e32), m32);
    const __m256i new_steps = _mm256_set_m128i(PermuteEpi32(Load32(in.step_v.data() + n), e32),
                                               PermuteEpi32(Load32(in.step_u.data() + n), e32));
    steps = _mm256_blendv_epi8(steps, new_steps, m32_both);
    ray = _mm_blendv_epi8(
        ray, PermuteEpi32(_mm_add_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_set1_epi32(next)), e32),
        m32);
    uv = _mm256_andnot_si256(m32_both, uv);
    counts = _mm_andnot_si128(m32, counts);
    active |= fill;
    next += __builtin_popcount(fill);
  }

  /// One jump or one cell of every active lane; the finished lanes' answers packed into
  /// `answers`' arrays from `finished` on.
  SLAM_AVX2_INLINE void Advance(const uint8_t* squares, __m256d res, WideRays& answers,
                                int32_t& finished) {
    if (active == 0) return;
    const __m256d one = _mm256_set1_pd(1.0), active64 = Mask64(active);
    const __m128i zero_i = _mm_setzero_si128(), one_i = _mm_set1_epi32(1);
    const __m128i u = _mm256_castsi256_si128(uv), v = _mm256_extracti128_si256(uv, 1);
    // WindowField::At (a 4-byte load at each byte's address, inside thanks to the padding).
    const __m256i offsets = _mm256_mullo_epi32(steps, uv);
    const __m128i at = _mm_add_epi32(
        base, _mm_add_epi32(_mm256_castsi256_si128(offsets), _mm256_extracti128_si256(offsets, 1)));
    const __m128i k =
        _mm_and_si128(_mm_mask_i32gather_epi32(zero_i, reinterpret_cast<const int*>(squares), at,
                                               Mask32(active), 1),
                      _mm_set1_epi32(0xff));
    const __m256d occupied = Widen(_mm_cmpeq_epi32(k, zero_i));
    // A hit, unless the ray only touches the cell.
    const __m256d leave_u =
        _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(_mm_add_epi32(u, one_i)), ox), ix);
    const __m256d leave_v =
        _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(_mm_add_epi32(v, one_i)), oy), iy);
    const __m256d t_leave = _mm256_min_pd(length, _mm256_min_pd(leave_v, leave_u));
    const __m256d hit = _mm256_and_pd(occupied, _mm256_cmp_pd(t_leave, t, _CMP_GT_OQ));
    // LeaveBox: out of the free square (of this cell when k <= 1).
    const __m128i reach = _mm_max_epi32(k, one_i);
    const __m128i end_u = _mm_add_epi32(u, reach), end_v = _mm_add_epi32(v, reach);
    const __m128i jump = _mm_cmpgt_epi32(k, one_i);
    const __m256d exit_u = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(end_u), ox), ix);
    const __m256d exit_v = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtepi32_pd(end_v), oy), iy);
    const __m256d t_exit = _mm256_min_pd(exit_v, exit_u);
    const __m128i counted = Narrow(_mm256_andnot_pd(hit, active64));
    const __m128i crossed = Narrow(_mm256_cmp_pd(_mm256_min_pd(length, t_exit), t, _CMP_GT_OQ));
    counts =
        _mm_add_epi32(counts, _mm_and_si128(_mm_and_si128(counted, jump), _mm_set1_epi32(0x10000)));
    counts = _mm_add_epi32(
        counts, _mm_and_si128(_mm_and_si128(_mm_andnot_si128(jump, counted), crossed), one_i));
    const __m256d out = _mm256_cmp_pd(t_exit, length, _CMP_GE_OQ);
    const __m256d slack =
        _mm256_mul_pd(_mm256_set1_pd(GridWalk::kCornerEpsilon), _mm256_add_pd(one, t_exit));
    const __m256d gap =
        _mm256_andnot_pd(_mm256_set1_pd(-0.0), _mm256_sub_pd(exit_u, exit_v));  // |exit_u - exit_v|
    const __m256d corner = _mm256_cmp_pd(gap, slack, _CMP_LE_OQ);
    const __m256d ahead = _mm256_add_pd(t_exit, slack);
    const __m128i along_u = _mm_min_epi32(
        _mm_max_epi32(_mm256_cvttpd_epi32(_mm256_add_pd(ox, _mm256_mul_pd(ax, ahead))), u),
        _mm_sub_epi32(end_u, one_i));
    const __m128i along_v = _mm_min_epi32(
        _mm_max_epi32(_mm256_cvttpd_epi32(_mm256_add_pd(oy, _mm256_mul_pd(ay, ahead))), v),
        _mm_sub_epi32(end_v, one_i));
    const __m128i across_u =
        Narrow(_mm256_or_pd(corner, _mm256_cmp_pd(exit_u, exit_v, _CMP_LT_OQ)));
    const __m128i across_v =
        Narrow(_mm256_or_pd(corner, _mm256_cmp_pd(exit_v, exit_u, _CMP_LT_OQ)));
    const __m256d t_hit = t;
    uv = _mm256_set_m128i(_mm_blendv_epi8(along_v, end_v, across_v),
                          _mm_blendv_epi8(along_u, end_u, across_u));
    t = _mm256_max_pd(t_exit, t);

    const unsigned done = active & Bits(_mm256_or_pd(hit, out));
    if (done == 0) return;
    // The finished lanes' answers, packed, then their lanes are free for the next rays.
    const __m256i c64 = Row8(kFourLanes.compress64[done]), c32 = Row8(kFourLanes.compress32[done]);
    const auto at_out = static_cast<size_t>(finished);
    Store32(answers.finished.data() + at_out, PermuteEpi32(ray, c32));
    Store32(answers.hit.data() + at_out, PermuteEpi32(_mm_and_si128(Narrow(hit), one_i), c32));
    Store32(answers.cells.data() + at_out,
            PermuteEpi32(_mm_and_si128(counts, _mm_set1_epi32(0xffff)), c32));
    Store32(answers.jumps.data() + at_out, PermuteEpi32(_mm_srli_epi32(counts, 16), c32));
    _mm256_storeu_pd(answers.distance.data() + at_out, PermutePd(_mm256_mul_pd(t_hit, res), c64));
    _mm256_storeu_pd(answers.exit.data() + at_out, PermutePd(_mm256_mul_pd(t_leave, res), c64));
    finished += __builtin_popcount(done);
    active &= ~done;
    free_lanes |= done;
  }
};

/// CastToObstacles(window, rays, hits) four rays at a time.
SLAM_AVX2_TARGET void CastFour(const MatchWindow& window, const std::vector<RayQuery>& rays,
                               std::vector<RayHit>& hits) {
  const size_t n = rays.size();
  hits.resize(n);
  thread_local WideRays in;
  in.Reserve(n);
  size_t uncovered = 0;
  const size_t covered = StartAvx2(window, rays, in, uncovered);
  const uint8_t* squares = window.free_squares();
  const __m256d res = _mm256_set1_pd(window.grid().geometry().resolution());
  Avx2Lanes lanes;
  const auto count = static_cast<int32_t>(covered);
  int32_t next = 0, finished = 0;
  while (true) {
    lanes.Fill(in, next, count);
    if (lanes.active == 0) break;
    lanes.Advance(squares, res, in, finished);
  }
  FinishWindowRays(window, rays, in, covered, uncovered, hits);
}

#undef SLAM_AVX2_INLINE
#undef SLAM_AVX2_TARGET

}  // namespace

void CastAvx512(const MatchWindow& window, const std::vector<RayQuery>& rays,
                std::vector<RayHit>& hits) {
  CastEight(window, rays, hits);
}

void CastAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays,
              std::vector<RayHit>& hits) {
  CastFour(window, rays, hits);
}

bool Avx512Supported() {
  static const bool supported = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("bmi2") &&
           __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
  }();
  return supported;
}

bool Avx2Supported() {
  static const bool supported = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") != 0;
  }();
  return supported;
}

#else  // no wide kernels on this architecture or compiler

bool Avx512Supported() { return false; }
bool Avx2Supported() { return false; }
void CastAvx512(const MatchWindow& window, const std::vector<RayQuery>& rays,
                std::vector<RayHit>& hits) {
  CastToObstacles(window, rays, hits, WindowKernel::kPortable);
}
void CastAvx2(const MatchWindow& window, const std::vector<RayQuery>& rays,
              std::vector<RayHit>& hits) {
  CastToObstacles(window, rays, hits, WindowKernel::kPortable);
}

#endif

}  // namespace slam::wide
