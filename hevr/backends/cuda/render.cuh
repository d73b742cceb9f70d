/*
 * hevr — the render path's backend operations as kernels, one independent item per thread.
 *
 * Built on mont.cuh (CIOS Montgomery multiplication on 32-bit limbs). Like it, this source compiles
 * for the GPU (nvcc / NVRTC: the extern "C" __global__ k_* kernels, one thread per item) and for the
 * host with a C compiler (the hevr_*_host functions: a loop over the same per-item device function),
 * so the host build — what hevr's test suite runs as the "cuda-host" backend — computes exactly what
 * the device computes. No thread cooperates with another.
 *
 * Residues. A batch is an (m, NL) array of little-endian 32-bit limbs. Between operations residues
 * mod N (N = n² of the key, odd) stay in Montgomery form x·R mod N, R = 2^(32·NL), so a chain of
 * products costs one CIOS product each: mont(x)·mont(y)·R^-1 = mont(x·y). The Montgomery form of 1 is
 * R mod N ("one" below); to_mont(x) = mont_mul(x, R² mod N); from_mont(y) = mont_mul(y, 1).
 *
 * Operations (items; what each thread computes):
 *   records <-> limbs   a big-endian byte record of width W <-> NL limbs (overflow flagged)
 *   range check         flag = !(0 < x < upper) on normal-form limbs
 *   mont convert        x·b·R^-1 with b = R² mod N (to Montgomery) or b = 1 (back)
 *   ray precompute      per voxel of a shared-bucket plan: c, c^(2^w), c^(2^(2w)), ..., J_v powers
 *   ray task            per task of a ProductPlan (hevr/backends/base.py), its kind's method:
 *                        ONES    running product c_1·c_2·…, n − 1 products;
 *                        SINGLE  c^x by left-to-right binary powering (x < 2^64);
 *                        HORNER  bucket multi-exponentiation: J windows of w bits, bucket d of window j
 *                                collects the c_v whose digit_j(x_v) = d; a window's Σ_d B_d^d by running
 *                                products (Π_d B_d^d = Π_k Π_{d≥k} B_d); windows joined by w squarings
 *                                and a product, or — when the window's top digit D reaches fold_min[w],
 *                                the smallest integer above 2^w − 0.85·w — by putting the accumulator
 *                                into an extra bucket 2^w (acc^(2^w)·T_j in 2^w − 1 more products);
 *                        SHARED  one bucket set for all windows, fed the precomputed c^(2^(w j)).
 *                       The method, window and fold rule are cpu.py's _execute, so the counts of
 *                       products and squarings (returned per task) are the CPU backend's.
 *   segment product     per (segment, component): the product of the segment's rows
 *   combine             per row of k values: Π_i v_i^E[ch][i] per channel ch; k ≤ 8 by the 2^k
 *                       subset products and Straus (one squaring, ≤ 1 product per exponent bit)
 *   pack                per group of J terms: Horner from the top digit, acc ← acc^(2^b)·T_j^R_j with
 *                       the b squarings and T_j^R_j's square-and-multiply interleaved, then · g^O·Σ
 *
 * Exponents wider than 64 bits (combine, pack) are arrays of 32-bit words, little-endian.
 * Scratch: every task / row gets its own buckets (device: a slice of one global buffer per thread of
 * a launch; host: one slice reused by the sequential loop).
 */
#include "mont.cuh"

#define HEVR_ONES 0
#define HEVR_SINGLE 1
#define HEVR_HORNER 2
#define HEVR_SHARED 3

typedef struct {
    const hevr_u32 *n;   /* the modulus N, nl limbs */
    const hevr_u32 *one; /* R mod N: 1 in Montgomery form */
    hevr_u32 ninv;       /* -N^-1 mod 2^32 */
    int nl;
} hevr_mod;

HEVR_HD void hevr_cpy(hevr_u32 *d, const hevr_u32 *s, int nl)
{
    for (int i = 0; i < nl; i++) d[i] = s[i];
}

/* acc = acc·b (Montgomery), in place; t: scratch of nl + 2 limbs */
HEVR_HD void hevr_mm(hevr_u32 *acc, const hevr_u32 *b, const hevr_mod *M, hevr_u32 *t)
{
    hevr_mont_mul(acc, b, M->n, M->ninv, M->nl, t, acc);
}

HEVR_HD int hevr_bits64(hevr_u64 x)
{
    int b = 0;
    while (x) { b++; x >>= 1; }
    return b;
}

HEVR_HD int hevr_bits_words(const hevr_u32 *e, int ew)
{
    for (int i = ew - 1; i >= 0; i--)
        if (e[i]) return 32 * i + hevr_bits64(e[i]);
    return 0;
}

HEVR_HD int hevr_bit(const hevr_u32 *e, int i)
{
    return (int)(e[i >> 5] >> (i & 31) & 1u);
}

/* out = base^e, left-to-right binary; out must not alias base */
HEVR_HD void hevr_pow_u64(hevr_u32 *out, const hevr_u32 *base, hevr_u64 e, const hevr_mod *M, hevr_u32 *t)
{
    int top = hevr_bits64(e);
    if (!top) { hevr_cpy(out, M->one, M->nl); return; }
    hevr_cpy(out, base, M->nl);
    for (int i = top - 2; i >= 0; i--) {
        hevr_mm(out, out, M, t);
        if (e >> i & 1) hevr_mm(out, base, M, t);
    }
}

/* out = base^e for an exponent of ew words; out must not alias base */
HEVR_HD void hevr_pow_words(hevr_u32 *out, const hevr_u32 *base, const hevr_u32 *e, int ew, const hevr_mod *M,
                            hevr_u32 *t)
{
    int top = hevr_bits_words(e, ew);
    if (!top) { hevr_cpy(out, M->one, M->nl); return; }
    hevr_cpy(out, base, M->nl);
    for (int i = top - 2; i >= 0; i--) {
        hevr_mm(out, out, M, t);
        if (hevr_bit(e, i)) hevr_mm(out, base, M, t);
    }
}

/* ---- records <-> limbs, range check, Montgomery conversion ------------------------------------- */

/* W big-endian bytes -> nl limbs; returns 1 if a non-zero byte does not fit nl limbs */
HEVR_HD int hevr_record_to_limbs(const unsigned char *rec, int width, int nl, hevr_u32 *x)
{
    int over = 0;
    for (int j = 0; j < nl; j++) x[j] = 0;
    for (int i = 0; i < width; i++) {
        int pos = width - 1 - i; /* byte significance */
        if (pos >= 4 * nl) { over |= rec[i] != 0; continue; }
        x[pos >> 2] |= (hevr_u32)rec[i] << (8 * (pos & 3));
    }
    return over;
}

/* nl limbs -> W big-endian bytes; returns 1 if the value needs more than W bytes */
HEVR_HD int hevr_limbs_to_record(const hevr_u32 *x, int nl, int width, unsigned char *rec)
{
    int over = 0;
    for (int i = 0; i < width; i++) {
        int pos = width - 1 - i;
        rec[i] = pos < 4 * nl ? (unsigned char)(x[pos >> 2] >> (8 * (pos & 3))) : 0;
    }
    for (int pos = width; pos < 4 * nl; pos++) over |= (x[pos >> 2] >> (8 * (pos & 3)) & 0xffu) != 0;
    return over;
}

/* 1 unless 0 < x < upper (upper == 0: no upper bound, only x != 0) */
HEVR_HD int hevr_out_of_range(const hevr_u32 *x, const hevr_u32 *upper, int nl)
{
    int nonzero = 0;
    for (int j = 0; j < nl; j++) nonzero |= x[j] != 0;
    if (!nonzero) return 1;
    if (!upper) return 0;
    for (int j = nl - 1; j >= 0; j--)
        if (x[j] != upper[j]) return x[j] > upper[j];
    return 1; /* x == upper */
}

/* ---- the per-brick multi-exponentiation ------------------------------------------------------- */

/* bucket i ← c (first entry: a copy) or bucket·c; counts the products */
HEVR_HD void hevr_put(hevr_u32 *B, unsigned char *used, long long i, const hevr_u32 *c, const hevr_mod *M,
                      hevr_u32 *t, long long *mul)
{
    hevr_u32 *b = B + i * M->nl;
    if (used[i]) { hevr_mm(b, c, M, t); (*mul)++; }
    else { hevr_cpy(b, c, M->nl); used[i] = 1; }
}

/* tot = Π_{d=1..hi-lo} B[lo+d]^d by running products, from the top bucket down (cpu.py's _combine);
 * returns the top digit (0: no bucket used, tot untouched). Costs (m − 1) + (top − 1) products. */
HEVR_HD long long hevr_bucket_sum(const hevr_u32 *B, const unsigned char *used, long long lo, long long hi,
                                  hevr_u32 *run, hevr_u32 *tot, const hevr_mod *M, hevr_u32 *t, long long *mul)
{
    long long top = 0;
    int nl = M->nl;
    for (long long i = hi; i > lo; i--) {
        if (used[i]) {
            if (!top) { hevr_cpy(run, B + i * nl, nl); top = i - lo; }
            else { hevr_mm(run, B + i * nl, M, t); (*mul)++; }
        }
        if (top) {
            if (i - lo == top) hevr_cpy(tot, run, nl);
            else { hevr_mm(tot, run, M, t); (*mul)++; }
        }
    }
    return top;
}

/* One plan task (kind, start, stop, w, J) into acc. cts: the component (Montgomery); pw, pw_off, pw_n: the
 * pw_n[v] shared-bucket powers of voxel v at pw + (pw_off[v] + j)·nl; counts: (products, squarings, powmod
 * bits), or products = -1 when a weight has more digits than the task's windows (a malformed plan). */
HEVR_HD void hevr_ray_task(const long long *task, const hevr_u32 *cts, const hevr_u32 *pw, const long long *pw_off,
                           const long long *pw_n, const long long *vl, const hevr_u64 *wl, int shared_w,
                           const long long *fold_min,
                           hevr_u32 *B, unsigned char *used, hevr_u32 *acc, hevr_u32 *run, hevr_u32 *tot,
                           const hevr_mod *M, hevr_u32 *t, long long *counts)
{
    int nl = M->nl;
    long long kind = task[0], s = task[1], e = task[2];
    int w = (int)task[3], n_win = (int)task[4];
    long long mul = 0, sq = 0, pow_bits = 0;
    if (kind == HEVR_ONES) {
        hevr_cpy(acc, cts + vl[s] * nl, nl);
        for (long long p = s + 1; p < e; p++) { hevr_mm(acc, cts + vl[p] * nl, M, t); mul++; }
    } else if (kind == HEVR_SINGLE) {
        hevr_pow_u64(acc, cts + vl[s] * nl, wl[s], M, t);
        pow_bits = hevr_bits64(wl[s]);
    } else if (kind == HEVR_HORNER) {
        long long size = 1LL << w, mask = size - 1, stride = size + 1;
        int have = 0;
        for (long long i = 0; i < stride * n_win; i++) used[i] = 0;
        for (long long p = s; p < e; p++) {
            const hevr_u32 *c = cts + vl[p] * nl;
            hevr_u64 x = wl[p];
            long long base = 0;
            while (x) {
                long long d = (long long)(x & (hevr_u64)mask);
                if (base >= stride * n_win) { counts[0] = -1; return; }
                if (d) hevr_put(B, used, base + d, c, M, t, &mul);
                x = w >= 64 ? 0 : x >> w;
                base += stride;
            }
        }
        for (int j = n_win - 1; j >= 0; j--) {
            long long lo = (long long)j * stride, top;
            if (have) {
                top = mask;
                while (top && !used[lo + top]) top--;
                if (top >= fold_min[w]) { /* acc^(2^w)·T_j with acc as bucket 2^w */
                    hevr_cpy(B + (lo + size) * nl, acc, nl);
                    used[lo + size] = 1;
                    hevr_bucket_sum(B, used, lo, lo + size, run, acc, M, t, &mul);
                    continue;
                }
                for (int i = 0; i < w; i++) { hevr_mm(acc, acc, M, t); sq++; }
            }
            if (hevr_bucket_sum(B, used, lo, lo + mask, run, tot, M, t, &mul)) {
                if (!have) { hevr_cpy(acc, tot, nl); have = 1; }
                else { hevr_mm(acc, tot, M, t); mul++; }
            }
        }
        if (!have) hevr_cpy(acc, M->one, nl); /* not reached: a task's weights are non-zero */
    } else { /* HEVR_SHARED */
        long long mask = (1LL << shared_w) - 1;
        for (long long i = 0; i <= mask; i++) used[i] = 0;
        for (long long p = s; p < e; p++) {
            const hevr_u32 *powers = pw + pw_off[vl[p]] * nl;
            hevr_u64 x = wl[p];
            int j = 0;
            while (x) {
                long long d = (long long)(x & (hevr_u64)mask);
                if (j >= pw_n[vl[p]]) { counts[0] = -1; return; }
                if (d) hevr_put(B, used, d, powers + (long long)j * nl, M, t, &mul);
                x = shared_w >= 64 ? 0 : x >> shared_w;
                j++;
            }
        }
        if (!hevr_bucket_sum(B, used, 0, mask, run, acc, M, t, &mul)) hevr_cpy(acc, M->one, nl);
    }
    counts[0] = mul;
    counts[1] = sq;
    counts[2] = pow_bits;
}

/* Powers c^(2^(w j)), j < n_pow, of one voxel into row (n_pow·nl limbs) */
HEVR_HD void hevr_ray_powers(const hevr_u32 *c, int n_pow, int w, hevr_u32 *row, const hevr_mod *M, hevr_u32 *t)
{
    int nl = M->nl;
    hevr_cpy(row, c, nl);
    for (int j = 1; j < n_pow; j++) {
        hevr_u32 *r = row + (long long)j * nl;
        hevr_cpy(r, r - nl, nl);
        for (int i = 0; i < w; i++) hevr_mm(r, r, M, t);
    }
}

/* ---- merging, combining, packing ------------------------------------------------------------- */

/* out = Π_{i=s..e-1} vals[i·k + j] */
HEVR_HD void hevr_segment(const hevr_u32 *vals, long long s, long long e, int k, int j, hevr_u32 *out,
                          const hevr_mod *M, hevr_u32 *t)
{
    int nl = M->nl;
    hevr_cpy(out, vals + (s * k + j) * nl, nl);
    for (long long i = s + 1; i < e; i++) hevr_mm(out, vals + (i * k + j) * nl, M, t);
}

/* One row of k bases -> C channels: out[ch] = Π_i base_i^E[ch][i]; E: (C, k, ew) words. sub: scratch of
 * 2^k values (k ≤ 8), tmp: nl limbs. */
HEVR_HD void hevr_combine_row(const hevr_u32 *bases, int k, int C, const hevr_u32 *E, int ew, hevr_u32 *out,
                              hevr_u32 *sub, hevr_u32 *tmp, const hevr_mod *M, hevr_u32 *t)
{
    int nl = M->nl;
    if (k <= 8) { /* sub[mask] = Π_{i in mask} base_i: 2^k − 1 − k products, shared by the channels */
        hevr_cpy(sub, M->one, nl);
        for (int i = 0; i < k; i++) {
            int bit = 1 << i;
            hevr_cpy(sub + (long long)bit * nl, bases + (long long)i * nl, nl);
            for (int m = 1; m < bit; m++)
                hevr_mont_mul(sub + (long long)m * nl, bases + (long long)i * nl, M->n, M->ninv, nl, t,
                              sub + (long long)(bit | m) * nl);
        }
    }
    for (int ch = 0; ch < C; ch++) {
        const hevr_u32 *ec = E + (long long)ch * k * ew;
        hevr_u32 *acc = out + (long long)ch * nl;
        int top = 0;
        for (int i = 0; i < k; i++) {
            int b = hevr_bits_words(ec + (long long)i * ew, ew);
            top = b > top ? b : top;
        }
        hevr_cpy(acc, M->one, nl);
        if (!top) continue;
        if (k <= 8) { /* Straus */
            for (int bit = top - 1; bit >= 0; bit--) {
                int m = 0;
                hevr_mm(acc, acc, M, t);
                for (int i = 0; i < k; i++) m |= hevr_bit(ec + (long long)i * ew, bit) << i;
                if (m) hevr_mm(acc, sub + (long long)m * nl, M, t);
            }
        } else {
            for (int i = 0; i < k; i++) {
                if (!hevr_bits_words(ec + (long long)i * ew, ew)) continue;
                hevr_pow_words(tmp, bases + (long long)i * nl, ec + (long long)i * ew, ew, M, t);
                hevr_mm(acc, tmp, M, t);
            }
        }
    }
}

/* One packed ciphertext from terms T[0..len) and exponents R (ew words each), digits of b bits:
 * Horner from the top digit; then · off (NULL: no offset). tmp: nl limbs. */
HEVR_HD void hevr_pack_group(const hevr_u32 *T, const hevr_u32 *R, int ew, long long len, int b,
                             const hevr_u32 *off, hevr_u32 *acc, hevr_u32 *tmp, const hevr_mod *M, hevr_u32 *t)
{
    int nl = M->nl;
    hevr_pow_words(acc, T + (len - 1) * nl, R + (len - 1) * ew, ew, M, t);
    for (long long j = len - 2; j >= 0; j--) {
        const hevr_u32 *Tj = T + j * nl, *Rj = R + j * ew;
        int r = hevr_bits_words(Rj, ew);
        if (r > b) { /* not reachable under the planner's bounds; exact anyway */
            for (int i = 0; i < b; i++) hevr_mm(acc, acc, M, t);
            hevr_pow_words(tmp, Tj, Rj, ew, M, t);
            hevr_mm(acc, tmp, M, t);
            continue;
        }
        for (int i = 0; i < b - r; i++) hevr_mm(acc, acc, M, t);
        for (int i = r - 1; i >= 0; i--) {
            hevr_mm(acc, acc, M, t);
            if (hevr_bit(Rj, i)) hevr_mm(acc, Tj, M, t);
        }
    }
    if (off) hevr_mm(acc, off, M, t);
}

/* ---- entry points: CUDA kernels, or host loops over the same items ------------------------------ */
#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
#define HEVR_ITEM(count) long long k = (long long)blockIdx.x * blockDim.x + threadIdx.x; if (k >= (count)) return;
#define HEVR_MOD hevr_mod M = {n, one, ninv, nl}; hevr_u32 t[HEVR_MAX_LIMBS + 2];

extern "C" __global__ void k_records_to_limbs(const unsigned char *rec, int width, int nl, long long count,
                                              hevr_u32 *x, unsigned char *over)
{
    HEVR_ITEM(count)
    over[k] = (unsigned char)hevr_record_to_limbs(rec + k * width, width, nl, x + k * nl);
}

extern "C" __global__ void k_limbs_to_records(const hevr_u32 *x, int nl, int width, long long count,
                                              unsigned char *rec, unsigned char *over)
{
    HEVR_ITEM(count)
    over[k] = (unsigned char)hevr_limbs_to_record(x + k * nl, nl, width, rec + k * width);
}

extern "C" __global__ void k_out_of_range(const hevr_u32 *x, const hevr_u32 *upper, int nl, long long count,
                                          unsigned char *bad)
{
    HEVR_ITEM(count)
    bad[k] = (unsigned char)hevr_out_of_range(x + k * nl, upper, nl);
}

extern "C" __global__ void k_mont_convert(const hevr_u32 *x, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv,
                                          int nl, long long count, hevr_u32 *out)
{
    HEVR_ITEM(count)
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    hevr_mont_mul(x + k * nl, b, n, ninv, nl, t, out + k * nl);
}

extern "C" __global__ void k_ray_powers(const hevr_u32 *cts, const long long *pre_v, const long long *pre_j,
                                        const long long *pre_start, int w, long long count, hevr_u32 *pw,
                                        const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_ITEM(count)
    HEVR_MOD
    hevr_ray_powers(cts + pre_v[k] * nl, (int)pre_j[k], w, pw + pre_start[k] * nl, &M, t);
}

/* Tasks first..first+count of a launch; scratch: per thread `slot` buckets of nl limbs and flags */
extern "C" __global__ void k_ray_tasks(const long long *tasks, long long first, long long count,
                                       const hevr_u32 *cts, const hevr_u32 *pw, const long long *pw_off,
                                       const long long *pw_n, const long long *vl, const hevr_u64 *wl, int shared_w,
                                       const long long *fold_min, hevr_u32 *buckets, unsigned char *used,
                                       long long slot, hevr_u32 *vals, long long *counts,
                                       const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_ITEM(count)
    HEVR_MOD
    hevr_u32 run[HEVR_MAX_LIMBS], tot[HEVR_MAX_LIMBS];
    long long q = first + k;
    hevr_ray_task(tasks + 5 * q, cts, pw, pw_off, pw_n, vl, wl, shared_w, fold_min, buckets + k * slot * nl,
                  used + k * slot, vals + q * nl, run, tot, &M, t, counts + 3 * q);
}

extern "C" __global__ void k_segments(const hevr_u32 *vals, const long long *indptr, int k_vals, long long count,
                                      hevr_u32 *out, const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_ITEM(count)
    HEVR_MOD
    long long seg = k / k_vals;
    hevr_segment(vals, indptr[seg], indptr[seg + 1], k_vals, (int)(k % k_vals), out + k * nl, &M, t);
}

extern "C" __global__ void k_combine(const hevr_u32 *vals, int k_vals, int C, const hevr_u32 *E, int ew,
                                     long long first, long long count, hevr_u32 *sub, hevr_u32 *out,
                                     const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_ITEM(count)
    HEVR_MOD
    hevr_u32 tmp[HEVR_MAX_LIMBS];
    long long r = first + k;
    long long slot = k_vals <= 8 ? (1LL << k_vals) : 0;
    hevr_combine_row(vals + r * k_vals * nl, k_vals, C, E, ew, out + r * C * nl, sub + k * slot * nl, tmp, &M, t);
}

extern "C" __global__ void k_pack(const hevr_u32 *T, const hevr_u32 *R, int ew, long long m, int per_pack, int b,
                                  const hevr_u32 *offs, long long count, hevr_u32 *out,
                                  const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_ITEM(count)
    HEVR_MOD
    hevr_u32 tmp[HEVR_MAX_LIMBS];
    long long s = k * per_pack, len = m - s < per_pack ? m - s : per_pack;
    const hevr_u32 *off = offs ? offs + (len == per_pack ? 0 : nl) : 0;
    hevr_pack_group(T + s * nl, R + s * ew, ew, len, b, off, out + k * nl, tmp, &M, t);
}
#else
#define HEVR_NL_CHECK if (nl < 1 || nl > HEVR_MAX_LIMBS) return -1;
#define HEVR_MOD hevr_mod M = {n, one, ninv, nl}; hevr_u32 t[HEVR_MAX_LIMBS + 2];

int hevr_records_to_limbs_host(const unsigned char *rec, int width, int nl, long long count, hevr_u32 *x,
                               unsigned char *over)
{
    HEVR_NL_CHECK
    for (long long k = 0; k < count; k++)
        over[k] = (unsigned char)hevr_record_to_limbs(rec + k * width, width, nl, x + k * nl);
    return 0;
}

int hevr_limbs_to_records_host(const hevr_u32 *x, int nl, int width, long long count, unsigned char *rec,
                               unsigned char *over)
{
    HEVR_NL_CHECK
    for (long long k = 0; k < count; k++)
        over[k] = (unsigned char)hevr_limbs_to_record(x + k * nl, nl, width, rec + k * width);
    return 0;
}

int hevr_out_of_range_host(const hevr_u32 *x, const hevr_u32 *upper, int nl, long long count, unsigned char *bad)
{
    HEVR_NL_CHECK
    for (long long k = 0; k < count; k++) bad[k] = (unsigned char)hevr_out_of_range(x + k * nl, upper, nl);
    return 0;
}

int hevr_mont_convert_host(const hevr_u32 *x, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, int nl,
                           long long count, hevr_u32 *out)
{
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    HEVR_NL_CHECK
    for (long long k = 0; k < count; k++) hevr_mont_mul(x + k * nl, b, n, ninv, nl, t, out + k * nl);
    return 0;
}

int hevr_ray_powers_host(const hevr_u32 *cts, const long long *pre_v, const long long *pre_j,
                         const long long *pre_start, int w, long long count, hevr_u32 *pw,
                         const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_NL_CHECK
    HEVR_MOD
    for (long long k = 0; k < count; k++)
        hevr_ray_powers(cts + pre_v[k] * nl, (int)pre_j[k], w, pw + pre_start[k] * nl, &M, t);
    return 0;
}

int hevr_ray_tasks_host(const long long *tasks, long long first, long long count, const hevr_u32 *cts,
                        const hevr_u32 *pw, const long long *pw_off, const long long *pw_n, const long long *vl,
                        const hevr_u64 *wl,
                        int shared_w, const long long *fold_min, hevr_u32 *buckets, unsigned char *used,
                        long long slot, hevr_u32 *vals, long long *counts,
                        const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    hevr_u32 run[HEVR_MAX_LIMBS], tot[HEVR_MAX_LIMBS];
    HEVR_NL_CHECK
    HEVR_MOD
    (void)slot; /* one thread at a time: every task reuses the first slot */
    for (long long q = first; q < first + count; q++)
        hevr_ray_task(tasks + 5 * q, cts, pw, pw_off, pw_n, vl, wl, shared_w, fold_min, buckets, used, vals + q * nl,
                      run, tot, &M, t, counts + 3 * q);
    return 0;
}

int hevr_segments_host(const hevr_u32 *vals, const long long *indptr, int k_vals, long long count, hevr_u32 *out,
                       const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    HEVR_NL_CHECK
    HEVR_MOD
    for (long long k = 0; k < count; k++)
        hevr_segment(vals, indptr[k / k_vals], indptr[k / k_vals + 1], k_vals, (int)(k % k_vals), out + k * nl,
                     &M, t);
    return 0;
}

int hevr_combine_host(const hevr_u32 *vals, int k_vals, int C, const hevr_u32 *E, int ew, long long first,
                      long long count, hevr_u32 *sub, hevr_u32 *out,
                      const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    hevr_u32 tmp[HEVR_MAX_LIMBS];
    HEVR_NL_CHECK
    HEVR_MOD
    for (long long r = first; r < first + count; r++)
        hevr_combine_row(vals + r * k_vals * nl, k_vals, C, E, ew, out + r * C * nl, sub, tmp, &M, t);
    return 0;
}

int hevr_pack_host(const hevr_u32 *T, const hevr_u32 *R, int ew, long long m, int per_pack, int b,
                   const hevr_u32 *offs, long long count, hevr_u32 *out,
                   const hevr_u32 *n, const hevr_u32 *one, hevr_u32 ninv, int nl)
{
    hevr_u32 tmp[HEVR_MAX_LIMBS];
    HEVR_NL_CHECK
    HEVR_MOD
    for (long long k = 0; k < count; k++) {
        long long s = k * per_pack, len = m - s < per_pack ? m - s : per_pack;
        const hevr_u32 *off = offs ? offs + (len == per_pack ? 0 : nl) : 0;
        hevr_pack_group(T + s * nl, R + s * ew, ew, len, b, off, out + k * nl, tmp, &M, t);
    }
    return 0;
}
#endif
