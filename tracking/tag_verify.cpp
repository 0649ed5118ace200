#include "tracking/tag_verify.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <functional>
#include <limits>
#include <memory>
#include <type_traits>
#include <utility>
#include <opencv2/imgproc.hpp>

#include "tracking/tag_detector.h"

namespace commonlight::tracking {
namespace {

// A template: the drawn tag's cells, `total` x `total`, 1 for white (row 0 at the tag's top),
// padded by one white cell on every side (stored (total + 2) x (total + 2)): the tag is seen on a
// white surround, so a sub-sample outside the drawn square reads the padding.
using Cells = std::vector<std::uint8_t>;

Cells cellsOf(int total, const std::function<bool(int, int)>& white) {
    const int padded = total + 2;
    Cells c(static_cast<std::size_t>(padded * padded), 1);
    for (int r = 0; r < total; ++r) {
        for (int col = 0; col < total; ++col)
            c[static_cast<std::size_t>((r + 1) * padded + col + 1)] = white(col, r) ? 1 : 0;
    }
    return c;
}

// 5-tap Gaussian kernels of the optics' blur levels tried (sigma 0: none); symmetric to the bit
// (k[0] == k[4], k[1] == k[3]: the same operations), which Matcher::blurLevels relies on.
std::vector<std::array<double, 5>> blurKernels(const std::vector<double>& sigmas) {
    std::vector<std::array<double, 5>> out;
    for (const double sigma : sigmas) {
        std::array<double, 5> k{0, 0, 1, 0, 0};
        if (sigma > 0) {
            double sum = 0;
            for (int i = 0; i < 5; ++i)
                sum += k[static_cast<std::size_t>(i)] = std::exp(-(i - 2) * (i - 2) / (2 * sigma * sigma));
            for (double& w : k) w /= sum;
        }
        out.push_back(k);
    }
    return out;
}

// The expected image of one template over the tag's box, and its NCC with the image there.
class Matcher {
public:
    static constexpr int kSub = 9;  // sub-samples per pixel (3 x 3)
    Matcher(const ImageView& gray8, const Linearizer& lin, const cv::Matx33d& pixel_to_cells, int total,
            const Eigen::Matrix2d& cells_per_px, int x0, int y0, int width, int height,
            std::vector<std::array<double, 5>> kernels, bool reference)
        : reference_(reference), total_(total), cells_per_px_(cells_per_px), width_(width), height_(height), kernels_(std::move(kernels)) {
        // Sub-samples at each pixel of the box (3 x 3), in cells of the drawn tag; the inner mask
        // keeps pixels whose centre is at least half a cell inside the drawn square (the outer half
        // of the white border sees the unknown surroundings through the blur).
        uv_.resize(static_cast<std::size_t>(width * height * kSub));
        range_.resize(static_cast<std::size_t>(width * height));
        std::vector<int> mask_lo(static_cast<std::size_t>(height), width), mask_hi(static_cast<std::size_t>(height), -1);
        const cv::Matx33d& h = pixel_to_cells;
        for (int y = 0; y < height; ++y) {
            for (int x = 0; x < width; ++x) {
                double u_lo = 1e300, u_hi = -1e300, v_lo = 1e300, v_hi = -1e300;
                bool finite = true;
                Eigen::Vector2d* uv = uv_.data() + static_cast<std::size_t>(y * width + x) * kSub;
                for (int j = 0; j < 3; ++j) {
                    const double py = y0 + y + (j - 1) / 3.0;
                    for (int i = 0; i < 3; ++i) {
                        // toCells written out (cv::Matx's product sums from 0 in this order).
                        const double px = x0 + x + (i - 1) / 3.0;
                        const double q0 = 0.0 + h(0, 0) * px + h(0, 1) * py + h(0, 2) * 1.0;
                        const double q1 = 0.0 + h(1, 0) * px + h(1, 1) * py + h(1, 2) * 1.0;
                        const double q2 = 0.0 + h(2, 0) * px + h(2, 1) * py + h(2, 2) * 1.0;
                        const double u = q0 / q2, v = q1 / q2;
                        *uv++ = Eigen::Vector2d(u, v);
                        finite = finite && std::isfinite(u) && std::isfinite(v);
                        u_lo = std::min(u_lo, u), u_hi = std::max(u_hi, u);
                        v_lo = std::min(v_lo, v), v_hi = std::max(v_hi, v);
                    }
                }
                // A sub-sample at infinity or NaN (a pixel on the tag plane's horizon): extremes
                // whose floors never agree, so that pixel always takes the sub-sample loop.
                range_[static_cast<std::size_t>(y * width + x)] =
                    finite ? Eigen::Vector4d(u_lo, u_hi, v_lo, v_hi) : Eigen::Vector4d(-1e300, 1e300, -1e300, 1e300);
                const Eigen::Vector2d c = toCells(pixel_to_cells, x0 + x, y0 + y);
                const bool inner = c.x() >= 0.5 && c.y() >= 0.5 && c.x() <= total - 0.5 && c.y() <= total - 0.5;
                if (inner) {
                    mask_.push_back(y * width + x);
                    mask_x_.push_back(x);
                    mask_y_.push_back(y);
                    mask_lo[static_cast<std::size_t>(y)] = std::min(mask_lo[static_cast<std::size_t>(y)], x);
                    mask_hi[static_cast<std::size_t>(y)] = std::max(mask_hi[static_cast<std::size_t>(y)], x);
                    image_.push_back(lin.lut[gray8.data[static_cast<std::size_t>((y0 + y) * gray8.stride + x0 + x)]] /
                                     255.0);
                }
            }
        }
        // What the NCC reads (docs/tracking.md, "Speed (issue 13)"): the vertical blur reads the
        // horizontally blurred rows within 2 px of a mask pixel (clamped rows are within them too),
        // at the mask's columns; the horizontal blur reads the model within 2 px of those. Each
        // row's spans cover them (a superset where a row's mask is not one run); the rest of the
        // box is never read, so it is neither rendered nor blurred.
        blur_lo_.assign(static_cast<std::size_t>(height), width);
        blur_hi_.assign(static_cast<std::size_t>(height), -1);
        render_lo_.assign(static_cast<std::size_t>(height), width);
        render_hi_.assign(static_cast<std::size_t>(height), -1);
        for (int y = 0; y < height; ++y) {
            for (int t = -2; t <= 2; ++t) {
                const int r = y + t;
                if (r < 0 || r >= height) continue;
                blur_lo_[static_cast<std::size_t>(y)] =
                    std::min(blur_lo_[static_cast<std::size_t>(y)], mask_lo[static_cast<std::size_t>(r)]);
                blur_hi_[static_cast<std::size_t>(y)] =
                    std::max(blur_hi_[static_cast<std::size_t>(y)], mask_hi[static_cast<std::size_t>(r)]);
            }
            if (blur_lo_[static_cast<std::size_t>(y)] <= blur_hi_[static_cast<std::size_t>(y)]) {
                render_lo_[static_cast<std::size_t>(y)] = std::max(0, blur_lo_[static_cast<std::size_t>(y)] - 2);
                render_hi_[static_cast<std::size_t>(y)] = std::min(width - 1, blur_hi_[static_cast<std::size_t>(y)] + 2);
            }
        }
        double mean = 0;
        for (double g : image_) mean += g;
        mean /= std::max<double>(1.0, static_cast<double>(image_.size()));
        for (double& g : image_) g -= mean;  // centred once: the NCC needs the image's deviations only
        for (double g : image_) image_ss_ += g * g, image_sum_ += g;
        model_.assign(static_cast<std::size_t>(width * height), 0.0);
        blurred_.assign(3 * model_.size(), 0.0);
        m_.resize(3 * mask_.size());
        // The mask as runs of consecutive pixels of one row, in its order (the vertical blur's
        // loops over them are contiguous, so the compiler vectorizes them).
        for (std::size_t i = 0; i < mask_.size(); ++i) {
            if (runs_.empty() || runs_.back().y != mask_y_[i] || runs_.back().x1 + 1 != mask_x_[i])
                runs_.push_back({mask_y_[i], mask_x_[i], mask_x_[i] - 1, static_cast<int>(i), {}});
            ++runs_.back().x1;
        }
        for (Run& r : runs_) {
            for (int t = -2; t <= 2; ++t)
                r.rows[static_cast<std::size_t>(t + 2)] = static_cast<std::size_t>(std::clamp(r.y + t, 0, height - 1) * width);
        }
    }
    std::size_t samples() const { return mask_.size(); }
    double imageStddev() const { return std::sqrt(image_ss_ / static_cast<double>(image_.size())); }
    // The best NCC (over the blur levels) over shifts of the template within +- search px (a grid
    // of `step` px, then step / 2 around its best). `ascent`: the grid is climbed from the
    // prediction (each step to the
    // best of the 3 x 3 shifts around the current one, until none is better) instead of tried
    // whole; where the correlation has one peak over the grid, as it has around a tag predicted
    // within the search, both end on the same shift. `evaluated`: the grid shifts tried.
    std::pair<double, Eigen::Vector2d> best(const Cells& white, double search, double step, bool ascent,
                                            int* evaluated = nullptr) const {
        double best_ncc = -2.0;
        Eigen::Vector2d best_shift = Eigen::Vector2d::Zero();
        const int steps = static_cast<int>(std::floor(search / step + 1e-9));
        const int side = 2 * steps + 1;
        int tried = 0;
        // The grid's shifts and half a step around them.
        prepareFixed(white, Eigen::Vector2d::Constant(step * steps + 0.5 * step));
        if (!ascent) {
            for (int sy = -steps; sy <= steps; ++sy) {
                for (int sx = -steps; sx <= steps; ++sx) {
                    const Eigen::Vector2d shift(step * sx, step * sy);
                    const double v = ncc(white, shift);
                    ++tried;
                    if (v > best_ncc) best_ncc = v, best_shift = shift;
                }
            }
        } else {
            // Each grid shift at most once (NaN: not tried yet).
            std::vector<double> grid(static_cast<std::size_t>(side * side), std::numeric_limits<double>::quiet_NaN());
            const auto at_grid = [&](int sx, int sy) {
                double& v = grid[static_cast<std::size_t>((sy + steps) * side + sx + steps)];
                if (std::isnan(v)) {
                    v = ncc(white, Eigen::Vector2d(step * sx, step * sy));
                    ++tried;
                }
                return v;
            };
            int cx = 0, cy = 0;
            best_ncc = at_grid(0, 0);
            for (;;) {
                int nx = cx, ny = cy;
                double next = best_ncc;
                for (int sy = std::max(cy - 1, -steps); sy <= std::min(cy + 1, steps); ++sy) {
                    for (int sx = std::max(cx - 1, -steps); sx <= std::min(cx + 1, steps); ++sx) {
                        const double v = at_grid(sx, sy);
                        if (v > next) next = v, nx = sx, ny = sy;
                    }
                }
                if (nx == cx && ny == cy) break;  // strictly better each step: it ends
                cx = nx, cy = ny, best_ncc = next;
            }
            best_shift = Eigen::Vector2d(step * cx, step * cy);
        }
        if (evaluated) *evaluated = tried;
        const Eigen::Vector2d coarse = best_shift;
        for (int sy = -1; sy <= 1; ++sy) {
            for (int sx = -1; sx <= 1; ++sx) {
                if (sx == 0 && sy == 0) continue;
                const Eigen::Vector2d shift = coarse + Eigen::Vector2d(0.5 * step * sx, 0.5 * step * sy);
                const double v = ncc(white, shift);
                if (v > best_ncc) best_ncc = v, best_shift = shift;
            }
        }
        releaseFixed();
        return {best_ncc, best_shift};
    }
    // Prepares `white` for calls of ncc with shifts of at most `bound` px each way (either
    // component): a pixel whose sub-samples, under every such shift, lie in cells of one colour
    // (the cells between the floors of its extremes moved by the largest shift in cells, which
    // bound those of any smaller shift: the subtraction and the floor are monotonic) takes that
    // colour into the model now, once; ncc renders only the others (`variable_`) while the shift
    // is within the bound and the template this one. Off for reference_ncc (the plain loops).
    void prepareFixed(const Cells& white, const Eigen::Vector2d& bound) const {
        fixed_for_ = nullptr;
        if (reference_) return;
        const Eigen::Matrix2d a = cells_per_px_.cwiseAbs();
        fixed_d_ = a * bound * (1.0 + 1e-9);  // a margin for the roundings of the shifts
        const int padded = total_ + 2;
        const std::uint8_t* cells = white.data();
        // White cells summed over the padded template's rectangles from its top left (one more
        // row and column of zeros first): a rectangle is one colour when it has none or all.
        const int stride = padded + 1;
        sat_.assign(static_cast<std::size_t>(stride * stride), 0);
        for (int r = 0; r < padded; ++r) {
            for (int c = 0; c < padded; ++c) {
                sat_[static_cast<std::size_t>((r + 1) * stride + c + 1)] =
                    cells[r * padded + c] + sat_[static_cast<std::size_t>(r * stride + c + 1)] +
                    sat_[static_cast<std::size_t>((r + 1) * stride + c)] - sat_[static_cast<std::size_t>(r * stride + c)];
            }
        }
        variable_.clear();
        for (int y = 0; y < height_; ++y) {
            for (int x = render_lo_[static_cast<std::size_t>(y)]; x <= render_hi_[static_cast<std::size_t>(y)]; ++x) {
                const int p = y * width_ + x;
                const double* range = range_[static_cast<std::size_t>(p)].data();
                // The lowest floors under the largest shift, the highest under the most negative.
                const auto [col_lo, col_hi] = paddedFloors(range, fixed_d_.x(), -fixed_d_.x(), total_);
                const auto [row_lo, row_hi] = paddedFloors(range + 2, fixed_d_.y(), -fixed_d_.y(), total_);
                // Padded rows row_lo + 1 .. row_hi + 1, columns likewise: sat_ rows and columns one on.
                const auto at = [&](int r, int c) { return sat_[static_cast<std::size_t>(r * stride + c)]; };
                const int white_cells = at(row_hi + 2, col_hi + 2) - at(row_lo + 1, col_hi + 2) - at(row_hi + 2, col_lo + 1) +
                                        at(row_lo + 1, col_lo + 1);
                const int area = (row_hi - row_lo + 1) * (col_hi - col_lo + 1);
                if (white_cells == 0 || white_cells == area)
                    model_[static_cast<std::size_t>(p)] = white_cells ? 1.0 : 0.0;
                else
                    variable_.push_back(p);
            }
        }
        fixed_for_ = cells;
    }
    void releaseFixed() const { fixed_for_ = nullptr; }
    // The NCC at one shift.
    double at(const Cells& white, const Eigen::Vector2d& shift_px) const { return ncc(white, shift_px); }
    // The best NCC on a 3 x 3 grid of `step` px around `centre`.
    double bestAround(const Cells& white, const Eigen::Vector2d& centre, double step) const {
        double best_ncc = -2.0;
        prepareFixed(white, centre.cwiseAbs() + Eigen::Vector2d::Constant(step));
        for (int sy = -1; sy <= 1; ++sy) {
            for (int sx = -1; sx <= 1; ++sx)
                best_ncc = std::max(best_ncc, ncc(white, centre + Eigen::Vector2d(step * sx, step * sy)));
        }
        releaseFixed();
        return best_ncc;
    }

private:
    static Eigen::Vector2d toCells(const cv::Matx33d& h, double x, double y) {
        const cv::Vec3d q = h * cv::Vec3d(x, y, 1.0);
        return {q[0] / q[2], q[1] / q[2]};
    }
    // floor(a - da) and floor(b - db), each within [-1, total]: a sub-sample outside the drawn
    // square reads the padding's white (NaN too). Truncation corrected below zero, after
    // clamping; both at once where SSE2 is (std::floor is a libm call or a longer sequence
    // without SSE4.1, and this is the NCC's innermost loop). The same operations either way, so
    // the same integers.
    static std::pair<int, int> paddedFloors(const double* ab, double da, double db, int total) {
#if defined(__SSE2__)
        __m128d v = _mm_sub_pd(_mm_loadu_pd(ab), _mm_set_pd(db, da));
        v = _mm_max_pd(v, _mm_set1_pd(-1.0));  // v > -1 ? v : -1 (NaN: -1)
        v = _mm_min_pd(v, _mm_set1_pd(static_cast<double>(total)));
        const __m128d truncated = _mm_cvtepi32_pd(_mm_cvttpd_epi32(v));
        const __m128d below = _mm_and_pd(_mm_cmpgt_pd(truncated, v), _mm_set1_pd(1.0));
        const __m128i f = _mm_cvttpd_epi32(_mm_sub_pd(truncated, below));
        return {_mm_cvtsi128_si32(f), _mm_cvtsi128_si32(_mm_shuffle_epi32(f, 1))};
#else
        const auto one = [&](double v) {
            v = v > -1.0 ? v : -1.0;
            v = v < total ? v : static_cast<double>(total);
            const int i = static_cast<int>(v);
            return i - (static_cast<double>(i) > v ? 1 : 0);
        };
        return {one(ab[0] - da), one(ab[1] - db)};
#endif
    }
    // Bit 0: a - da >= col, bit 1: b - db >= row (the same differences as paddedFloors').
    static int pastBoundaries(const double* ab, double da, double db, int col, int row) {
#if defined(__SSE2__)
        const __m128d v = _mm_sub_pd(_mm_loadu_pd(ab), _mm_set_pd(db, da));
        return _mm_movemask_pd(_mm_cmpge_pd(v, _mm_set_pd(static_cast<double>(row), static_cast<double>(col))));
#else
        return (ab[0] - da >= col ? 1 : 0) | (ab[1] - db >= row ? 2 : 0);
#endif
    }
    // The template moved by shift_px, blurred by each level in turn: the best NCC.
    double ncc(const Cells& white, const Eigen::Vector2d& shift_px) const {
        // A pixel sees the tag plane at its position minus the shift.
        const Eigen::Vector2d d = cells_per_px_ * shift_px;
        // count / 9 for each count, as the division gives it.
        static constexpr std::array<double, kSub + 1> kFraction = {0.0 / kSub, 1.0 / kSub, 2.0 / kSub, 3.0 / kSub,
                                                                   4.0 / kSub, 5.0 / kSub, 6.0 / kSub, 7.0 / kSub,
                                                                   8.0 / kSub, 9.0 / kSub};
        const int padded = total_ + 2;
        const std::uint8_t* cells = white.data();
        const auto render = [&](std::size_t p) {
            const Eigen::Vector2d* uv = uv_.data() + p * kSub;
            // The pixel's sub-samples lie in the cells between its extremes' (the subtraction
            // and the floor are monotonic): within one cell, or cells of one colour, the pixel
            // is that colour without the nine lookups.
            const double* range = range_[p].data();
            const auto [col_lo, col_hi] = paddedFloors(range, d.x(), d.x(), total_);
            const auto [row_lo, row_hi] = paddedFloors(range + 2, d.y(), d.y(), total_);
            int count = 0;
            const std::uint8_t* corner = cells + (row_lo + 1) * padded + col_lo + 1;
            if (col_lo == col_hi && row_lo == row_hi) {
                count = kSub * corner[0];
            } else if (col_hi - col_lo <= 1 && row_hi - row_lo <= 1 && corner[0] == corner[col_hi - col_lo] &&
                       corner[0] == corner[(row_hi - row_lo) * padded] &&
                       corner[0] == corner[(row_hi - row_lo) * padded + col_hi - col_lo]) {
                // Across a boundary between cells of one colour (up to 2 x 2 cells).
                count = kSub * corner[0];
            } else if (col_hi - col_lo <= 1 && row_hi - row_lo <= 1) {
                // Within 2 x 2 cells: a sub-sample's cell is the corner one, or the next
                // across each boundary it reaches (floor(v) > n - 1 exactly when v >= n).
                const std::array<int, 4> colour = {corner[0], corner[col_hi - col_lo], corner[(row_hi - row_lo) * padded],
                                                   corner[(row_hi - row_lo) * padded + col_hi - col_lo]};
                for (int k = 0; k < kSub; ++k)
                    count += colour[static_cast<std::size_t>(pastBoundaries(uv[k].data(), d.x(), d.y(), col_lo + 1, row_lo + 1))];
            } else {
                for (int k = 0; k < kSub; ++k) {
                    const auto [col, row] = paddedFloors(uv[k].data(), d.x(), d.y(), total_);
                    count += cells[(row + 1) * padded + col + 1];
                }
            }
            model_[p] = kFraction[static_cast<std::size_t>(count)];
        };
        if (fixed_for_ == cells && std::abs(d.x()) <= fixed_d_.x() && std::abs(d.y()) <= fixed_d_.y()) {
            // The template prepared (prepareFixed): the other pixels' values are in the model.
            for (const int p : variable_) render(static_cast<std::size_t>(p));
        } else {
            fixed_for_ = nullptr;  // the model rendered whole: its fixed pixels' values are this shift's
            for (int y = 0; y < height_; ++y) {
                for (int x = render_lo_[static_cast<std::size_t>(y)]; x <= render_hi_[static_cast<std::size_t>(y)]; ++x)
                    render(static_cast<std::size_t>(y * width_ + x));
            }
        }
        double best = -2.0;
        const double n = static_cast<double>(mask_.size());
        // The NCC of one blur level's values at the mask's pixels, the plain way (reference_ncc:
        // the level's mean subtracted, then the two sums); `sm`: the sum of the values.
        const auto score = [&](const double* m, double sm) {
            sm /= n;
            double smg = 0, smm = 0;
            for (std::size_t i = 0; i < mask_.size(); ++i) {
                const double a = m[i] - sm;
                smg += a * image_[i];
                smm += a * a;
            }
            if (smm > 0 && image_ss_ > 0) best = std::max(best, smg / std::sqrt(smm * image_ss_));
        };
        // The same from one pass of three sums (TagVerifyOptions::reference_ncc off): sum m,
        // sum m^2 and sum m g (g: the image's deviations), then the centred sums as
        // sum m g - mean(m) sum g and sum m^2 - mean(m) sum m. Not the same roundings as the plain
        // way (within 1e-12 of it; docs/tracking.md, "Speed (issue 13)").
        const auto fromSums = [&](double s, double q, double c) {
            const double mean = s / n;
            const double smg = c - mean * image_sum_, smm = q - mean * s;
            // A flat model (every value equal) has smm 0 but for rounding: not scored, as above.
            if (smm > 1e-12 * q && image_ss_ > 0) best = std::max(best, smg / std::sqrt(smm * image_ss_));
        };
        const auto scoreFast = [&](const double* m) {
            std::size_t i = 0;
            double s = 0, q = 0, c = 0;
#if defined(__SSE2__)
            __m128d vs = _mm_setzero_pd(), vq = _mm_setzero_pd(), vc = _mm_setzero_pd();
            for (; i + 2 <= mask_.size(); i += 2) {
                const __m128d v = _mm_loadu_pd(m + i);
                vs = _mm_add_pd(vs, v);
                vq = _mm_add_pd(vq, _mm_mul_pd(v, v));
                vc = _mm_add_pd(vc, _mm_mul_pd(v, _mm_loadu_pd(image_.data() + i)));
            }
            double lanes[6];
            _mm_storeu_pd(lanes, vs), _mm_storeu_pd(lanes + 2, vq), _mm_storeu_pd(lanes + 4, vc);
            s = lanes[0] + lanes[1], q = lanes[2] + lanes[3], c = lanes[4] + lanes[5];
#endif
            for (; i < mask_.size(); ++i) s += m[i], q += m[i] * m[i], c += m[i] * image_[i];
            fromSums(s, q, c);
        };
        // The blur levels three at a time (one pass over the model's rows and the mask's runs for
        // the three), the no-blur level as the model itself. The best is a maximum: the levels'
        // order does not change it.
        std::array<const std::array<double, 5>*, 3> group{};
        int grouped = 0;
        const auto flush = [&] {
            if (grouped == 3) blurLevels<3>(group);
            if (grouped == 2) blurLevels<2>(group);
            if (grouped == 1) blurLevels<1>(group);
            for (int g = 0; g < grouped; ++g) scoreFast(m_.data() + static_cast<std::size_t>(g) * mask_.size());
            grouped = 0;
        };
        for (const auto& k : kernels_) {
            if (reference_) {
                score(m_.data(), referenceLevel(k));
                continue;
            }
            if (k[0] == 0.0 && k[1] == 0.0 && k[2] == 1.0 && k[3] == 0.0 && k[4] == 0.0) {
                // No blur: the model itself at the mask's pixels.
                double s = 0, q = 0, c = 0;
                for (std::size_t i = 0; i < mask_.size(); ++i) {
                    const double v = model_[static_cast<std::size_t>(mask_[i])];
                    s += v, q += v * v, c += v * image_[i];
                }
                fromSums(s, q, c);
                continue;
            }
            group[static_cast<std::size_t>(grouped++)] = &k;
            if (grouped == 3) flush();
        }
        flush();
        return best > -2.0 ? best : 0.0;
    }

    // One level the plain way (TagVerifyOptions::reference_ncc; the loops before issue 13's pass
    // 9): each tap added in turn, pixel by pixel, into m_; returns the sum of m_.
    double referenceLevel(const std::array<double, 5>& k) const {
        double sm = 0;
        if (k[0] == 0.0 && k[1] == 0.0 && k[2] == 1.0 && k[3] == 0.0 && k[4] == 0.0) {
            for (std::size_t i = 0; i < mask_.size(); ++i) sm += m_[i] = model_[static_cast<std::size_t>(mask_[i])];
            return sm;
        }
        for (int y = 0; y < height_; ++y) {
            for (int x = blur_lo_[static_cast<std::size_t>(y)]; x <= blur_hi_[static_cast<std::size_t>(y)]; ++x) {
                double v = 0;
                for (int t = -2; t <= 2; ++t)
                    v += k[static_cast<std::size_t>(t + 2)] * model_[static_cast<std::size_t>(y * width_ + std::clamp(x + t, 0, width_ - 1))];
                blurred_[static_cast<std::size_t>(y * width_ + x)] = v;
            }
        }
        for (std::size_t i = 0; i < mask_.size(); ++i) {
            double v = 0;
            for (int t = -2; t <= 2; ++t) {
                v += k[static_cast<std::size_t>(t + 2)] *
                     blurred_[static_cast<std::size_t>(std::clamp(mask_y_[i] + t, 0, height_ - 1) * width_ + mask_x_[i])];
            }
            sm += m_[i] = v;
        }
        return sm;
    }
    // G blur levels of the model: the Gaussian each way, edges clamped (rows over the spans the
    // vertical pass reads, columns at the mask's pixels only; the clamping only within 2 px of an
    // edge), into m_'s first G blocks. Each value is k0 (outer pair) + k1 (inner pair) + k2 centre,
    // the kernels being symmetric: not the plain loops' roundings (referenceLevel sums the five
    // products left to right; the NCCs agree within 1e-12).
    template <int G>
    void blurLevels(const std::array<const std::array<double, 5>*, 3>& levels) const {
        const std::size_t area = static_cast<std::size_t>(width_ * height_), n = mask_.size();
        double kk[G][5];  // the levels' taps, held in registers
        for (int g = 0; g < G; ++g) {
            for (int t = 0; t < 5; ++t) kk[g][t] = (*levels[static_cast<std::size_t>(g)])[static_cast<std::size_t>(t)];
        }
        // One output of each level from the five values around it (lane-wise the same operations
        // where two neighbours are done at once). The kernels are symmetric (blurKernels): the
        // outer pairs are added first, once for the levels.
        const auto taps = [&](auto a, auto b, auto c, auto d, auto e, auto store) {
#if defined(__SSE2__)
            if constexpr (!std::is_same_v<decltype(a), double>) {  // __m128d
                const __m128d ae = _mm_add_pd(a, e), bd = _mm_add_pd(b, d);
                for (int g = 0; g < G; ++g) {
                    const double* k = kk[g];
                    const __m128d v = _mm_add_pd(_mm_mul_pd(_mm_set1_pd(k[0]), ae), _mm_mul_pd(_mm_set1_pd(k[1]), bd));
                    store(g, _mm_add_pd(v, _mm_mul_pd(_mm_set1_pd(k[2]), c)));
                }
            } else
#endif
            {
                const double ae = a + e, bd = b + d;
                for (int g = 0; g < G; ++g) store(g, kk[g][0] * ae + kk[g][1] * bd + kk[g][2] * c);
            }
        };
        for (int y = 0; y < height_; ++y) {
            const double* row = model_.data() + static_cast<std::size_t>(y * width_);
            double* out = blurred_.data() + static_cast<std::size_t>(y * width_);
            const int lo = blur_lo_[static_cast<std::size_t>(y)], hi = blur_hi_[static_cast<std::size_t>(y)];
            for (int x = lo; x <= hi; ++x) {
                const std::size_t ox = static_cast<std::size_t>(x);
#if defined(__SSE2__)
                if (x >= 2 && x + 1 <= std::min(hi, width_ - 3)) {  // x and x + 1, neither clamped
                    const double* q = row + x;
                    taps(_mm_loadu_pd(q - 2), _mm_loadu_pd(q - 1), _mm_loadu_pd(q), _mm_loadu_pd(q + 1), _mm_loadu_pd(q + 2),
                         [&](int g, __m128d v) { _mm_storeu_pd(out + static_cast<std::size_t>(g) * area + ox, v); });
                    ++x;
                    continue;
                }
#endif
                const auto at = [&](int t) { return row[std::clamp(x + t, 0, width_ - 1)]; };
                taps(at(-2), at(-1), at(0), at(1), at(2),
                     [&](int g, double v) { out[static_cast<std::size_t>(g) * area + ox] = v; });
            }
        }
        for (const Run& r : runs_) {
            for (int g = 0; g < G; ++g) {
                const double* k = kk[g];
                const double* base = blurred_.data() + static_cast<std::size_t>(g) * area;
                const double *r0 = base + r.rows[0], *r1 = base + r.rows[1], *r2 = base + r.rows[2], *r3 = base + r.rows[3],
                             *r4 = base + r.rows[4];
                double* out = m_.data() + static_cast<std::size_t>(g) * n + static_cast<std::size_t>(r.i0 - r.x0);
                int x = r.x0;
#if defined(__SSE2__)
                const __m128d k0 = _mm_set1_pd(k[0]), k1 = _mm_set1_pd(k[1]), k2 = _mm_set1_pd(k[2]);
                for (; x + 1 <= r.x1; x += 2) {
                    const __m128d ae = _mm_add_pd(_mm_loadu_pd(r0 + x), _mm_loadu_pd(r4 + x));
                    const __m128d bd = _mm_add_pd(_mm_loadu_pd(r1 + x), _mm_loadu_pd(r3 + x));
                    const __m128d v = _mm_add_pd(_mm_mul_pd(k0, ae), _mm_mul_pd(k1, bd));
                    _mm_storeu_pd(out + x, _mm_add_pd(v, _mm_mul_pd(k2, _mm_loadu_pd(r2 + x))));
                }
#endif
                for (; x <= r.x1; ++x) out[x] = k[0] * (r0[x] + r4[x]) + k[1] * (r1[x] + r3[x]) + k[2] * r2[x];
            }
        }
    }

    bool reference_ = false;
    int total_;
    Eigen::Matrix2d cells_per_px_;
    int width_, height_;
    std::vector<std::array<double, 5>> kernels_;
    std::vector<Eigen::Vector2d> uv_;
    std::vector<Eigen::Vector4d> range_;  // per pixel, its sub-samples' min and max u, min and max v
    std::vector<int> mask_, mask_x_, mask_y_;
    struct Run {
        int y, x0, x1, i0;  // row, first and last column, index of the first in mask_
        std::array<std::size_t, 5> rows{};  // offsets of rows y - 2 .. y + 2 (clamped to the box)
    };
    std::vector<Run> runs_;
    // Per row of the box: the columns the horizontal blur computes, and those the model renders
    // (empty when lo > hi).
    std::vector<int> blur_lo_, blur_hi_, render_lo_, render_hi_;
    std::vector<double> image_;  // linear, minus its mean
    double image_ss_ = 0.0;
    double image_sum_ = 0.0;  // of the deviations: 0 but for rounding
    mutable std::vector<double> model_, blurred_, m_;
    // prepareFixed's template (null: none), its bound in cells each way, the pixels rendered.
    mutable const std::uint8_t* fixed_for_ = nullptr;
    mutable Eigen::Vector2d fixed_d_ = Eigen::Vector2d::Zero();
    mutable std::vector<int> variable_, sat_;  // and the template's summed-area table
};

}  // namespace

TagVerifyResult verifyPredictedTag(const ImageView& gray8, const CameraModel& camera, const TagPattern& pattern,
                                   const std::vector<const TagPattern*>& others, double size,
                                   const Rigid3d& cam_from_tag, const TagVerifyOptions& options,
                                   const Eigen::Vector2d* known_at_px) {
    TagVerifyResult out;
    if (gray8.format != PixelFormat::kGray8 || !cam_from_tag.isValid() || !(size > 0) || pattern.total() <= 0) {
        out.reason = "bad input";
        return out;
    }
    // Step 1: the predicted black square and drawn square (white border included).
    for (int k = 0; k < 4; ++k) {
        const Eigen::Vector3d p = cam_from_tag * tagCornerInTag(k, size);
        const auto px = p.z() > 0 ? camera.project(p) : std::nullopt;
        if (!px) {
            out.reason = "behind the camera";
            return out;
        }
        out.corners[static_cast<std::size_t>(k)] = *px;
    }
    for (int k = 0; k < 4; ++k)
        out.side_px +=
            0.25 *
            (out.corners[static_cast<std::size_t>(k)] - out.corners[static_cast<std::size_t>((k + 1) % 4)]).norm();
    // The range applies to the shorter span (between the midpoints of opposite sides): a tag seen
    // 75-80 degrees off its normal is 7-10 px across and 30-45 px along, and the detector misses it.
    const auto mid = [&](int a, int b) {
        return 0.5 * (out.corners[static_cast<std::size_t>(a)] + out.corners[static_cast<std::size_t>(b)]);
    };
    out.span_px = std::min((mid(0, 1) - mid(2, 3)).norm(), (mid(1, 2) - mid(3, 0)).norm());
    if (out.span_px < options.min_side_px || out.span_px > options.max_side_px) {
        out.reason = "predicted side outside the tried range";
        return out;
    }
    // A foreshortened tag (its mean side over the range) only while its cells across are too fine
    // for the detector (the tracker's, decimated by 2 in tracking mode, found the bundled desk
    // sample's tags, 27 px along and 18-19 px across, in most frames; verifying them in the others
    // cost 2.7 ms per frame).
    if (out.side_px > options.max_side_px && out.span_px > options.max_foreshortened_span_px) {
        out.reason = "foreshortened tag wide enough for the detector";
        out.wide_enough_to_detect = true;
        return out;
    }
    const int total = pattern.total();
    const double half = 0.5 * total * pattern.cell() * size;
    // Outer corners in the tag frame, and in cells (u right, v down from the top row).
    const std::array<Eigen::Vector2d, 4> tag_xy = {Eigen::Vector2d(-half, -half), Eigen::Vector2d(half, -half),
                                                   Eigen::Vector2d(half, half), Eigen::Vector2d(-half, half)};
    std::array<cv::Point2f, 4> cells_pts, pixel_pts;
    double xmin = 1e30, ymin = 1e30, xmax = -1e30, ymax = -1e30;
    for (std::size_t k = 0; k < 4; ++k) {
        const Eigen::Vector3d p = cam_from_tag * Eigen::Vector3d(tag_xy[k].x(), tag_xy[k].y(), 0.0);
        const auto px = p.z() > 0 ? camera.project(p) : std::nullopt;
        if (!px) {
            out.reason = "behind the camera";
            return out;
        }
        pixel_pts[k] = cv::Point2f(static_cast<float>(px->x()), static_cast<float>(px->y()));
        cells_pts[k] = cv::Point2f(static_cast<float>((tag_xy[k].x() + half) / (2 * half) * total),
                                   static_cast<float>((half - tag_xy[k].y()) / (2 * half) * total));
        xmin = std::min(xmin, px->x()), xmax = std::max(xmax, px->x());
        ymin = std::min(ymin, px->y()), ymax = std::max(ymax, px->y());
    }
    const double m = options.edge_margin_px;
    if (xmin < m || ymin < m || xmax > gray8.width - 1 - m || ymax > gray8.height - 1 - m) {
        out.reason = "not inside the image";
        return out;
    }
    const cv::Matx33d to_cells(cv::getPerspectiveTransform(pixel_pts.data(), cells_pts.data()));
    const Eigen::Vector2d centre = 0.25 * (out.corners[0] + out.corners[1] + out.corners[2] + out.corners[3]);
    const int x0 = static_cast<int>(std::floor(xmin)), y0 = static_cast<int>(std::floor(ymin));
    const int x1 = static_cast<int>(std::ceil(xmax)), y1 = static_cast<int>(std::ceil(ymax));
    const auto kernels = blurKernels(options.blur_sigma_px);
    // A matcher for a pixel-to-cell homography over the box (with the local Jacobian at the tag's
    // centre, for shifting the template).
    const auto makeMatcher = [&](const cv::Matx33d& h) {
        const auto cellsAt = [&](const Eigen::Vector2d& p) {
            const cv::Vec3d q = h * cv::Vec3d(p.x(), p.y(), 1.0);
            return Eigen::Vector2d(q[0] / q[2], q[1] / q[2]);
        };
        // Cells per pixel: the difference over one pixel (centre +- 0.5 px). Until the seventh round
        // it was halved, so that a shift moved the template by half of what it moved the corners.
        Eigen::Matrix2d jac;
        jac.col(0) = cellsAt(centre + Eigen::Vector2d(0.5, 0)) - cellsAt(centre - Eigen::Vector2d(0.5, 0));
        jac.col(1) = cellsAt(centre + Eigen::Vector2d(0, 0.5)) - cellsAt(centre - Eigen::Vector2d(0, 0.5));
        return std::make_unique<Matcher>(gray8, Linearizer::get(options.srgb), h, total, jac, x0, y0, x1 - x0 + 1,
                                         y1 - y0 + 1, kernels, options.reference_ncc);
    };
    std::unique_ptr<Matcher> matcher = makeMatcher(to_cells);
    if (matcher->samples() < 16) {
        out.reason = "too few pixels";
        return out;
    }
    if (matcher->imageStddev() < options.min_contrast) {
        out.reason = "no contrast where the tag is predicted";
        return out;
    }
    // Step 2: the tag's pattern.
    const Cells own = cellsOf(total, [&](int c, int r) { return pattern.white(c, r); });
    const auto [ncc, shift] = matcher->best(own, options.search_px, options.search_step_px, options.search_ascent,
                                             &out.grid_shifts_tried);
    for (auto& c : out.corners) c += shift;
    out.ncc = ncc;
    out.shift_px = shift;
    // Step 3: the alternatives.
    const int border = static_cast<int>(std::lround(1.0 / pattern.cell()));
    const int b0 = (total - border) / 2;
    const auto square = [&](int c, int r) { return c < b0 || r < b0 || c >= b0 + border || r >= b0 + border; };
    if (ncc < options.min_ncc) {
        out.reason = "the pattern does not match the image";
        return out;
    }
    if (known_at_px && (centre - *known_at_px).norm() <= 0.5 * out.span_px) {
        out.alternatives_skipped = true;
        out.ok = true;
        return out;
    }
    out.ncc_square = matcher->bestAround(cellsOf(total, square), shift, options.search_step_px);
    if (ncc - out.ncc_square < options.min_margin_square) {
        out.reason = "a plain black square matches as well";
        return out;
    }
    for (const TagPattern* other : others) {
        if (!other || other->total() != total) continue;
        out.ncc_other = std::max(out.ncc_other,
                                 matcher->at(cellsOf(total, [&](int c, int r) { return other->white(c, r); }), shift));
    }
    if (ncc - out.ncc_other < options.min_margin_other) {
        out.reason = "another id matches as well";
        return out;
    }
    out.ok = true;
    return out;
}

}  // namespace commonlight::tracking
