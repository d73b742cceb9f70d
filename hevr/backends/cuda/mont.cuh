/*
 * hevr — batched Montgomery multiplication on 32-bit limbs, one product per thread.
 *
 * The same source compiles three ways:
 *   - for the GPU through CuPy/NVRTC (__CUDACC__ or __CUDACC_RTC__ defined): the __global__
 *     kernel k_mont_mul below, one thread per product;
 *   - for the host with a C compiler (cc -O3 -shared -fPIC -x c -std=c99): the extern function
 *     hevr_mont_mul_batch, a loop over the same per-product body. hevr's test suite builds it
 *     and checks every result against gmpy2, so the arithmetic is tested on machines without a GPU.
 * render.cuh includes it for the render path's kernels.
 *
 * Numbers are little-endian arrays of NL 32-bit limbs. For an odd modulus N < 2^(32·NL) and
 * R = 2^(32·NL), mont_mul(a, b) = a·b·R^-1 mod N for a < R, b < N (CIOS: coarsely integrated operand
 * scanning, Koç et al. 1996): per limb b_i of b, m = (t + a·b_i)_0·(−N^-1 mod 2^32) mod 2^32 and
 * t = (t + a·b_i + m·N) / 2^32, both products accumulated in one pass over the limbs. Then
 * t < R + N < 2^(32·NL+1) after every step and t < (a·b + (R−1)·N)/R < 2N at the end, so one
 * conditional subtraction gives the result in [0, N) (a < R allows to_mont of any NL-limb value).
 * Work: 2·NL² 32×32→64-bit multiply-adds.
 */
#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
#define HEVR_HD __device__ __forceinline__
#define HEVR_INLINE __device__ __forceinline__
#define HEVR_CALL __device__ __noinline__ /* one copy of the product per module: short NVRTC builds */
#define HEVR_RESTRICT __restrict__
typedef unsigned int hevr_u32;
typedef unsigned long long hevr_u64;
#else
#define HEVR_HD static inline
#define HEVR_INLINE static inline __attribute__((always_inline))
#define HEVR_CALL static inline
#define HEVR_RESTRICT restrict
#include <stdint.h>
typedef uint32_t hevr_u32;
typedef uint64_t hevr_u64;
#endif

#define HEVR_MAX_LIMBS 128 /* 4096 bits: n² of a 2048-bit key */

/* The CIOS body; inlined where nl is a constant, so the compiler unrolls the small sizes. */
HEVR_INLINE void hevr_cios(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, int nl,
                           hevr_u32 *HEVR_RESTRICT t, hevr_u32 *out)
{
    for (int i = 0; i < nl + 2; i++) t[i] = 0;
    for (int i = 0; i < nl; i++) {
        /* t = (t + a·b_i + m·n) / 2^32 in one pass: two independent carry chains (c for a·b_i, d for
         * m·n) instead of two loops, the same sums limb by limb; t < 2^(32·nl+1) throughout */
        hevr_u32 bi = b[i];
        hevr_u64 s = (hevr_u64)a[0] * bi + t[0], c = s >> 32;
        hevr_u32 m = (hevr_u32)s * ninv;            /* t + m·n ≡ 0 mod 2^32 */
        hevr_u64 r = (hevr_u64)m * n[0] + (hevr_u32)s, d = r >> 32;
        for (int j = 1; j < nl; j++) {
            s = (hevr_u64)a[j] * bi + t[j] + c;
            c = s >> 32;
            r = (hevr_u64)m * n[j] + (hevr_u32)s + d;
            d = r >> 32;
            t[j - 1] = (hevr_u32)r;
        }
        s = (hevr_u64)t[nl] + c + d;
        t[nl - 1] = (hevr_u32)s;
        t[nl] = (hevr_u32)(s >> 32);
    }
    /* t < 2n: subtract n once if t >= n (t has nl + 1 limbs) */
    int ge = t[nl] != 0;
    if (!ge) {
        ge = 1;                                     /* equal counts as >= */
        for (int j = nl - 1; j >= 0; j--) {
            if (t[j] != n[j]) { ge = t[j] > n[j]; break; }
        }
    }
    if (ge) {
        hevr_u64 borrow = 0;
        for (int j = 0; j < nl; j++) {
            hevr_u64 d = (hevr_u64)t[j] - n[j] - borrow;
            out[j] = (hevr_u32)d;
            borrow = (d >> 63) & 1;
        }
    } else {
        for (int j = 0; j < nl; j++) out[j] = t[j];
    }
}

#ifdef HEVR_CIOS_REG
/* An experiment for the GPU (off unless HEVR_CIOS_REG is defined; hevr bench --gpu measures it
 * against the shipped body): the same CIOS for the 2048-bit key's sizes (nl = 64: p², 128: n²)
 * with the accumulator t in a local array whose every index is a constant once the inner loop is
 * unrolled, so it can live in registers, not in local memory; a and n are read through volatile
 * pointers so the compiler does not hoist all 2·nl of their limbs into registers too (and spill),
 * the trick of the measured prototype (../shared/reference/gpu-prototype). Same sums, same result. */
#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
#define HEVR_UNROLL _Pragma("unroll")
#else
#define HEVR_UNROLL
#endif
#define HEVR_CIOS_FIXED(NLC)                                                                               \
    HEVR_INLINE void hevr_cios_##NLC(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, \
                                     hevr_u32 *out)                                                      \
    {                                                                                                     \
        hevr_u32 t[NLC + 2];                                                                              \
        const volatile hevr_u32 *av = a, *nv = n;                                                         \
        HEVR_UNROLL for (int i = 0; i < NLC + 2; i++) t[i] = 0;                                           \
        for (int i = 0; i < NLC; i++) {                                                                   \
            hevr_u32 bi = b[i];                                                                           \
            hevr_u64 s = (hevr_u64)av[0] * bi + t[0], c = s >> 32;                                        \
            hevr_u32 m = (hevr_u32)s * ninv;                                                              \
            hevr_u64 r = (hevr_u64)m * nv[0] + (hevr_u32)s, d = r >> 32;                                  \
            HEVR_UNROLL for (int j = 1; j < NLC; j++) {                                                   \
                s = (hevr_u64)av[j] * bi + t[j] + c;                                                      \
                c = s >> 32;                                                                              \
                r = (hevr_u64)m * nv[j] + (hevr_u32)s + d;                                                \
                d = r >> 32;                                                                              \
                t[j - 1] = (hevr_u32)r;                                                                   \
            }                                                                                             \
            s = (hevr_u64)t[NLC] + c + d;                                                                 \
            t[NLC - 1] = (hevr_u32)s;                                                                     \
            t[NLC] = (hevr_u32)(s >> 32);                                                                 \
        }                                                                                                 \
        int ge = t[NLC] != 0, lt = 0;  /* t >= n, from the top limb down, without a data-dependent break */ \
        HEVR_UNROLL for (int j = NLC - 1; j >= 0; j--) {                                                  \
            hevr_u32 nj = nv[j];                                                                          \
            ge |= !lt && t[j] > nj;                                                                       \
            lt |= !ge && t[j] < nj;                                                                       \
        }                                                                                                 \
        ge |= !lt;                                                                                        \
        hevr_u64 borrow = 0;                                                                              \
        HEVR_UNROLL for (int j = 0; j < NLC; j++) {                                                       \
            hevr_u64 dd = (hevr_u64)t[j] - (ge ? nv[j] : 0u) - borrow;                                    \
            out[j] = (hevr_u32)dd;                                                                        \
            borrow = (dd >> 63) & 1;                                                                      \
        }                                                                                                 \
    }
HEVR_CIOS_FIXED(64)
HEVR_CIOS_FIXED(128)
#if !defined(__CUDACC__) && !defined(__CUDACC_RTC__)
int hevr_experiment_cios_reg(void) { return 1; } /* the host build says the experiment is compiled in */
#endif
#endif

/* out = a·b·R^-1 mod n; a < 2^(32·nl), b < n; t: scratch of nl + 2 limbs. out may alias a or b (it is
 * written after their last read: acc = acc·b and acc = acc² in place), never n or t. The limb counts
 * of n² for 64- to 512-bit keys get their own unrolled copy of the same body. */
HEVR_CALL void hevr_mont_mul(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, int nl,
                             hevr_u32 *t, hevr_u32 *out)
{
    switch (nl) {
    case 4: hevr_cios(a, b, n, ninv, 4, t, out); break;
    case 8: hevr_cios(a, b, n, ninv, 8, t, out); break;
    case 16: hevr_cios(a, b, n, ninv, 16, t, out); break;
    case 32: hevr_cios(a, b, n, ninv, 32, t, out); break;
#ifdef HEVR_CIOS_REG
    case 64: hevr_cios_64(a, b, n, ninv, out); break;
    case 128: hevr_cios_128(a, b, n, ninv, out); break;
#endif
    default: hevr_cios(a, b, n, ninv, nl, t, out);
    }
}

#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
/* One thread per product: out[k] = a[k]·b[k]·R^-1 mod n, k < count; operands row-major, nl limbs each. */
extern "C" __global__ void k_mont_mul(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv,
                                      int nl, long long count, hevr_u32 *out)
{
    long long k = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= count) return;
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    hevr_mont_mul(a + k * nl, b + k * nl, n, ninv, nl, t, out + k * nl);
}
#else
/* The host build: the same body over a batch. Returns 0, or -1 when nl is out of range. */
int hevr_mont_mul_batch(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, int nl,
                        long long count, hevr_u32 *out)
{
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    if (nl < 1 || nl > HEVR_MAX_LIMBS) return -1;
    for (long long k = 0; k < count; k++)
        hevr_mont_mul(a + k * nl, b + k * nl, n, ninv, nl, t, out + k * nl);
    return 0;
}
#endif
