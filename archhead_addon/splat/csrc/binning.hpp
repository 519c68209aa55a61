// One global depth sort, then binning into square tiles (16 or 32 pixels: Kernels::tile). Every
// step is deterministic and independent of the thread count: a stable sort on the float64 depth
// (ties keep input order), and counting passes whose output does not depend on how they are split.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

namespace ah {

constexpr int kMaxTile = 32;  // pixels: the largest tile of any compositing path

// Stable sort of ids by positive float64 keys: an LSD radix sort (3 passes of 11 bits, the
// counts of all passes in one read; a pass in which every key agrees is skipped) on their
// float32 roundings, whose bit patterns order like the values, then each run of equal
// float32 keys stably in float64 order (runs are rare and short: the float32 key tells
// depths 6e-8 apart). The same order as a stable sort on the float64 keys.
inline std::vector<int32_t> sort_by_depth(const std::vector<int32_t>& ids,
                                          const std::vector<double>& depth) {
    constexpr int kBits = 11, kPasses = 3, kBuckets = 1 << kBits;
    const size_t n = ids.size();
    std::vector<uint32_t> keys(n), keys_tmp(n);
    std::vector<int32_t> out(ids), tmp(n);
    std::vector<size_t> count(kPasses * (kBuckets + 1), 0);
    for (size_t i = 0; i < n; ++i) {
        const float key = float(depth[ids[i]]);
        std::memcpy(&keys[i], &key, sizeof key);
        for (int p = 0; p < kPasses; ++p)
            ++count[p * (kBuckets + 1) + ((keys[i] >> (kBits * p)) & (kBuckets - 1)) + 1];
    }
    for (int p = 0; p < kPasses; ++p) {
        size_t* c = &count[p * (kBuckets + 1)];
        if (std::find(c + 1, c + kBuckets + 1, n) != c + kBuckets + 1) continue;
        for (int b = 0; b < kBuckets; ++b) c[b + 1] += c[b];
        for (size_t i = 0; i < n; ++i) {
            const size_t dst = c[(keys[i] >> (kBits * p)) & (kBuckets - 1)]++;
            keys_tmp[dst] = keys[i];
            tmp[dst] = out[i];
        }
        keys.swap(keys_tmp);
        out.swap(tmp);
    }
    for (size_t i = 0, j; i < n; i = j) {
        for (j = i + 1; j < n && keys[j] == keys[i];) ++j;
        if (j - i > 1)
            std::stable_sort(out.begin() + i, out.begin() + j,
                             [&](int32_t a, int32_t b) { return depth[a] < depth[b]; });
    }
    return out;
}

// Tile lists. tile_start has tiles + 1 entries; tile_ids[tile_start[t] .. tile_start[t+1])
// are the Gaussians touching tile t, front to back. For the backward reduction, tile-list
// entry p has the slot slot_of[p]: the i-th Gaussian of slot_ids owns slots isect_start[i] ..
// isect_start[i+1] (its tiles in increasing order), so the tiles scatter their gradient
// records there and each Gaussian reads its own contiguously. slot_ids orders the visible
// Gaussians by their first tile (front to back within one): a tile's entries then land in a
// few nearby runs of slots, where depth order spread them over the whole array and the
// backward's compositing loop stalled on the cache misses of its writes.
struct Bins {
    int tile = 0, tiles_x = 0, tiles_y = 0;  // tile: its edge in pixels
    std::vector<int32_t> sorted;             // visible Gaussians, front to back
    std::vector<int32_t> slot_ids;           // visible Gaussians by first tile, then front to back
    std::vector<int64_t> tile_start, isect_start;
    std::vector<int32_t> tile_ids;
    std::vector<int64_t> slot_of;
};

// bbox: per Gaussian inclusive pixel ranges x0, x1, y0, y1 (4 ints). The sorted list is cut
// into `chunks` contiguous pieces counted and filled in parallel; each piece writes after
// the pieces before it in every tile, so the lists equal the serial ones for any count.
inline void bin_tiles(Bins& B, std::vector<int32_t> sorted, const std::vector<int32_t>& bbox,
                      int width, int height, int tile, int chunks) {
    B.tile = tile;
    const int shift = __builtin_ctz(unsigned(tile));  // tile: a power of two
    B.tiles_x = (width + tile - 1) / tile;
    B.tiles_y = (height + tile - 1) / tile;
    const int64_t n_tiles = int64_t(B.tiles_x) * B.tiles_y;
    const int64_t n = int64_t(sorted.size());
    B.sorted = std::move(sorted);
    auto tiles_of = [&](int64_t k, int& tx0, int& tx1, int& ty0, int& ty1) {
        if (k + 16 < n) __builtin_prefetch(&bbox[4 * size_t(B.sorted[k + 16])]);  // random reads
        const int32_t* b = &bbox[4 * size_t(B.sorted[k])];
        tx0 = b[0] >> shift, tx1 = b[1] >> shift, ty0 = b[2] >> shift, ty1 = b[3] >> shift;
    };
    // cursor[c * n_tiles + t]: first holds chunk c's count in tile t, then its write position
    std::vector<int64_t> cursor(size_t(chunks) * n_tiles, 0);
    // per sorted Gaussian: its first tile (then its rank in slot order), its tile count
    std::vector<int64_t> first(n), isects(n);
#pragma omp parallel for num_threads(chunks) schedule(static, 1)
    for (int c = 0; c < chunks; ++c) {
        int64_t* count = &cursor[size_t(c) * n_tiles];
        for (int64_t k = n * c / chunks; k < n * (c + 1) / chunks; ++k) {
            int tx0, tx1, ty0, ty1;
            tiles_of(k, tx0, tx1, ty0, ty1);
            const int64_t t = int64_t(ty0) * B.tiles_x + tx0;
            const int w = tx1 - tx0, h = ty1 - ty0;
            if (w <= 1 && h <= 1) {  // most Gaussians: 1 to 2 x 2 tiles, without branches
                const int64_t down = h * int64_t(B.tiles_x);
                ++count[t];
                count[t + w] += w;
                count[t + down] += h;
                count[t + down + w] += w & h;
            } else {
                for (int ty = ty0; ty <= ty1; ++ty)
                    for (int tx = tx0; tx <= tx1; ++tx) ++count[int64_t(ty) * B.tiles_x + tx];
            }
            first[k] = t;
            isects[k] = int64_t(tx1 - tx0 + 1) * (ty1 - ty0 + 1);
        }
    }
    // slot order: a stable counting sort by first tile; then each sorted Gaussian's first slot
    std::vector<int64_t> bucket(n_tiles + 1, 0);
    for (int64_t k = 0; k < n; ++k) ++bucket[first[k] + 1];
    for (int64_t t = 0; t < n_tiles; ++t) bucket[t + 1] += bucket[t];
    B.slot_ids.resize(n);
    B.isect_start.assign(n + 1, 0);
    for (int64_t k = 0; k < n; ++k) {
        const int64_t i = bucket[first[k]]++;
        B.slot_ids[i] = B.sorted[k];
        B.isect_start[i + 1] = isects[k];
        first[k] = i;  // from here: the rank in slot order
    }
    for (int64_t i = 0; i < n; ++i) B.isect_start[i + 1] += B.isect_start[i];
    B.tile_start.assign(n_tiles + 1, 0);
    for (int64_t t = 0; t < n_tiles; ++t) {
        int64_t pos = B.tile_start[t];
        for (int c = 0; c < chunks; ++c) {
            const int64_t count = cursor[size_t(c) * n_tiles + t];
            cursor[size_t(c) * n_tiles + t] = pos;
            pos += count;
        }
        B.tile_start[t + 1] = pos;
    }
    B.tile_ids.resize(B.tile_start[n_tiles]);
    B.slot_of.resize(B.tile_start[n_tiles]);
#pragma omp parallel for num_threads(chunks) schedule(static, 1)
    for (int c = 0; c < chunks; ++c) {
        int64_t* pos = &cursor[size_t(c) * n_tiles];
        int32_t spare_id;  // where the branch-free case writes the tiles a Gaussian lacks
        int64_t spare_slot;
        for (int64_t k = n * c / chunks; k < n * (c + 1) / chunks; ++k) {
            int tx0, tx1, ty0, ty1;
            tiles_of(k, tx0, tx1, ty0, ty1);
            int64_t e = B.isect_start[first[k]];  // its first slot
            const int32_t id = B.sorted[k];
            const int w = tx1 - tx0, h = ty1 - ty0;
            if (w <= 1 && h <= 1) {
                const int64_t t = int64_t(ty0) * B.tiles_x + tx0, down = h * int64_t(B.tiles_x);
                // its tiles in increasing order: t, t + 1 (if w), t + down (if h), both
                const int64_t tiles[4] = {t, t + w, t + down, t + down + w};
                const int has[4] = {1, w, h, w & h};
                const int64_t slot[4] = {e, e + 1, e + 1 + w, e + 3};
                for (int i = 0; i < 4; ++i) {
                    int64_t& p = pos[tiles[i]];
                    *(has[i] ? &B.tile_ids[0] + p : &spare_id) = id;
                    *(has[i] ? &B.slot_of[0] + p : &spare_slot) = slot[i];
                    p += has[i];
                }
            } else {
                for (int ty = ty0; ty <= ty1; ++ty)
                    for (int tx = tx0; tx <= tx1; ++tx) {
                        const int64_t p = pos[int64_t(ty) * B.tiles_x + tx]++;
                        B.tile_ids[p] = id;
                        B.slot_of[p] = e++;
                    }
            }
        }
    }
}

}  // namespace ah
