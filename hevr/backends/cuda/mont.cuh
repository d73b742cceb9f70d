/*
 * hevr — batched Montgomery multiplication on 32-bit limbs, one product per thread.
 *
 * The same source compiles three ways:
 *   - for the GPU through CuPy/NVRTC (__CUDACC__ or __CUDACC_RTC__ defined): the __global__
 *     kernel k_mont_mul below, one thread per product;
 *   - for the host with a C compiler (gcc -O2 -shared -fPIC -x c): the extern function
 *     hevr_mont_mul_batch, a loop over the same per-product body. hevr's test suite builds it
 *     and checks every result against gmpy2, so the arithmetic is tested on machines without a GPU.
 *
 * Numbers are little-endian arrays of NL 32-bit limbs. For an odd modulus N < 2^(32·NL) and
 * R = 2^(32·NL), mont_mul(a, b) = a·b·R^-1 mod N for a, b < N (CIOS: coarsely integrated operand
 * scanning, Koç et al. 1996): per limb b_i of b, t += a·b_i, then m = t_0·(−N^-1 mod 2^32) mod 2^32
 * and t = (t + m·N) / 2^32. The invariant t < 2N holds after every step, so one conditional
 * subtraction at the end gives the result in [0, N). Work: 2·NL² 32×32→64-bit multiply-adds.
 */
#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
#define HEVR_HD __device__ __forceinline__
typedef unsigned int hevr_u32;
typedef unsigned long long hevr_u64;
#else
#define HEVR_HD static inline
#include <stdint.h>
typedef uint32_t hevr_u32;
typedef uint64_t hevr_u64;
#endif

#define HEVR_MAX_LIMBS 128 /* 4096 bits: n² of a 2048-bit key */

/* out = a·b·R^-1 mod n; a, b < n; t: scratch of nl + 2 limbs; out may alias neither a nor b. */
HEVR_HD void hevr_mont_mul(const hevr_u32 *a, const hevr_u32 *b, const hevr_u32 *n, hevr_u32 ninv, int nl,
                           hevr_u32 *t, hevr_u32 *out)
{
    for (int i = 0; i < nl + 2; i++) t[i] = 0;
    for (int i = 0; i < nl; i++) {
        hevr_u64 c = 0, s;
        hevr_u32 bi = b[i];
        for (int j = 0; j < nl; j++) {              /* t += a·b_i */
            s = (hevr_u64)a[j] * bi + t[j] + c;
            t[j] = (hevr_u32)s;
            c = s >> 32;
        }
        s = (hevr_u64)t[nl] + c;
        t[nl] = (hevr_u32)s;
        t[nl + 1] = (hevr_u32)(s >> 32);
        hevr_u32 m = t[0] * ninv;                   /* t + m·n ≡ 0 mod 2^32 */
        s = (hevr_u64)m * n[0] + t[0];
        c = s >> 32;
        for (int j = 1; j < nl; j++) {              /* t = (t + m·n) / 2^32 */
            s = (hevr_u64)m * n[j] + t[j] + c;
            t[j - 1] = (hevr_u32)s;
            c = s >> 32;
        }
        s = (hevr_u64)t[nl] + c;
        t[nl - 1] = (hevr_u32)s;
        t[nl] = t[nl + 1] + (hevr_u32)(s >> 32);
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
