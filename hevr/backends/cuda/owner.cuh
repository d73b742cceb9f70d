/*
 * hevr — encryption and decryption as kernels, one value per thread (issue 26): owner-side and
 * public-key encryption, CRT decryption.
 *
 * The CPU path of hevr/crypto/owner.py, per value (its module docstring proves the distribution):
 *   mask_p = G_p^a mod p²,  mask_q = G_q^b mod q²       a, b uniform in [0, p−1), [0, q−1), drawn on the
 *                                                     host from os.urandom (never a GPU PRNG)
 *   c_p = (1 + x·n)·mask_p mod p²,  c_q likewise      x the signed mantissa (int64); a negative x is the
 *                                                     residue n + x, and (n + x)·n ≡ x·n mod p² since p² | n²
 *   c   = c_q + q²·((c_p − c_q)·(q²)^-1 mod p²)       the CRT, as the CPU path writes it: c < n²
 * G^a comes from the fixed-base window table T[i][d] = G^(d·2^(w·i)) mod p² (Montgomery form, rows of
 * 2^w entries of nl limbs): G^a = Π_i T[i][digit_i(a)], one CIOS product per non-zero w-bit digit. The
 * tables come from the same OwnerEncryptor as the CPU path's, so both draw from one distribution; the
 * ciphertexts differ only by the randomness. Output: c in normal form, NL limbs (n² of the key).
 *
 * Public-key encryption (hevr/crypto/keys.py PublicKey.encrypt): c = (1 + x·n)·r^n mod n², r uniform in
 * Z_n^* drawn on the host (os.urandom, gcd checked there); r^n by left-to-right binary powering mod n² in
 * Montgomery form; 1 + x·n < n² needs no reduction (|x| < n/3), a negative x is n² − |x|·n + 1.
 *
 * CRT decryption (hevr/crypto/paillier.py raw_decrypt_crt), per ciphertext c < n²:
 *   x   = c mod p²                                     Horner over chunks of c, in Montgomery form
 *   m_p = L_p(x^(p−1) mod p²)·h_p mod p,  L_p(y) = (y − 1)/p   the division exact: (y − 1)·p^-1 mod 2^(32k)
 *   m_q likewise;  m = m_p + p·((m_q − m_p)·p^-1 mod q)   in [0, n)
 *
 * Everything here but the products is linear-time limb arithmetic on values below p², q² or n².
 */
#include "mont.cuh"

/* w-bit digit i of an exponent of ew little-endian 32-bit words (w <= 16) */
HEVR_HD hevr_u32 hevr_digit(const hevr_u32 *e, int ew, int w, int i)
{
    int bit = w * i, word = bit >> 5, off = bit & 31;
    hevr_u64 v = word < ew ? e[word] : 0;
    if (word + 1 < ew) v |= (hevr_u64)e[word + 1] << 32;
    return (hevr_u32)((v >> off) & ((1u << w) - 1));
}

/* x >= y over nl limbs */
HEVR_HD int hevr_geq(const hevr_u32 *x, const hevr_u32 *y, int nl)
{
    for (int j = nl - 1; j >= 0; j--)
        if (x[j] != y[j]) return x[j] > y[j];
    return 1;
}

/* x -= y over nl limbs (x >= y) */
HEVR_HD void hevr_sub_in(hevr_u32 *x, const hevr_u32 *y, int nl)
{
    hevr_u64 borrow = 0;
    for (int j = 0; j < nl; j++) {
        hevr_u64 d = (hevr_u64)x[j] - y[j] - borrow;
        x[j] = (hevr_u32)d;
        borrow = (d >> 63) & 1;
    }
}

/* x = (x − y) mod P for x, y < P: on a borrow, + P (the wrap of 2^(32·nl) cancels) */
HEVR_HD void hevr_sub_mod(hevr_u32 *x, const hevr_u32 *y, const hevr_u32 *P, int nl)
{
    hevr_u64 borrow = 0;
    for (int j = 0; j < nl; j++) {
        hevr_u64 d = (hevr_u64)x[j] - y[j] - borrow;
        x[j] = (hevr_u32)d;
        borrow = (d >> 63) & 1;
    }
    if (borrow) {
        hevr_u64 c = 0;
        for (int j = 0; j < nl; j++) { c += (hevr_u64)x[j] + P[j]; x[j] = (hevr_u32)c; c >>= 32; }
    }
}

/* y = 1 + (neg ? −y : y) mod P for y < P (the plaintext factor 1 + x·N of a signed mantissa x) */
HEVR_HD void hevr_one_plus(hevr_u32 *y, int neg, const hevr_u32 *P, int nl, hevr_u32 *tmp)
{
    if (neg) { /* y = 0 − y mod P */
        for (int j = 0; j < nl; j++) tmp[j] = 0;
        hevr_sub_mod(tmp, y, P, nl);
        for (int j = 0; j < nl; j++) y[j] = tmp[j];
    }
    for (int j = 0; j < nl; j++) tmp[j] = j == 0 ? P[0] - 1 : P[j];  /* y + 1 = y − (P − 1) mod P */
    hevr_sub_mod(y, tmp, P, nl);
}

/* out += a·b (schoolbook), kept to NL limbs (the caller knows the sum fits) */
HEVR_HD void hevr_mul_add(hevr_u32 *out, int NL, const hevr_u32 *a, int na, const hevr_u32 *b, int nb)
{
    for (int i = 0; i < na; i++) {
        hevr_u64 c = 0;
        for (int j = 0; j < nb && i + j < NL; j++) {
            c += (hevr_u64)a[i] * b[j] + out[i + j];
            out[i + j] = (hevr_u32)c;
            c >>= 32;
        }
        for (int k = i + nb; c && k < NL; k++) { c += out[k]; out[k] = (hevr_u32)c; c >>= 32; }
    }
}

/* out = c mod P2 in Montgomery form (c: NL limbs, any size): Horner over chunks of nl limbs from the
 * top, A' = A·R + chunk, i.e. A'·R = mont(A·R, R²) + mont(chunk, R²) mod P2 */
HEVR_HD void hevr_reduce_mont(const hevr_u32 *c, int NL, const hevr_u32 *P2, const hevr_u32 *R2, hevr_u32 ninv,
                              int nl, hevr_u32 *out, hevr_u32 *chunk, hevr_u32 *t)
{
    for (int j = 0; j < nl; j++) out[j] = 0;
    int chunks = (NL + nl - 1) / nl;
    for (int k = chunks - 1; k >= 0; k--) {
        for (int j = 0; j < nl; j++) chunk[j] = k * nl + j < NL ? c[k * nl + j] : 0;
        hevr_mont_mul(out, R2, P2, ninv, nl, t, out);
        hevr_mont_mul(chunk, R2, P2, ninv, nl, t, chunk);
        hevr_u64 s = 0;
        for (int j = 0; j < nl; j++) { s += (hevr_u64)out[j] + chunk[j]; out[j] = (hevr_u32)s; s >>= 32; }
        if (s || hevr_geq(out, P2, nl)) hevr_sub_in(out, P2, nl);
    }
}

/* one prime square: out = (1 + x·N)·G^a mod P in normal form; NR = (N mod P)·R mod P (Montgomery form) */
HEVR_HD void hevr_owner_half(long long x, const hevr_u32 *a, int ew, const hevr_u32 *T, int rows, int w,
                             const hevr_u32 *P, const hevr_u32 *one, hevr_u32 ninv, int nl, const hevr_u32 *NR,
                             hevr_u32 *out, hevr_u32 *acc, hevr_u32 *t)
{
    for (int j = 0; j < nl; j++) acc[j] = one[j];
    for (int i = 0; i < rows; i++) {
        hevr_u32 d = hevr_digit(a, ew, w, i);
        if (d) hevr_mont_mul(acc, T + (((long long)i << w) + d) * nl, P, ninv, nl, t, acc);
    }
    /* acc = G^a·R mod P. y = |x|·N mod P (|x| < 2^64 in two limbs; CIOS with NR gives the normal form) */
    hevr_u64 ax = x < 0 ? (hevr_u64)(-(x + 1)) + 1 : (hevr_u64)x;
    for (int j = 0; j < nl; j++) out[j] = 0;
    if (nl > 1) {
        out[0] = (hevr_u32)ax;
        out[1] = (hevr_u32)(ax >> 32);
    } else {
        out[0] = (hevr_u32)(ax % P[0]); /* P < 2^32: |x| reduced first (CIOS wants a < 2^(32·nl)) */
    }
    hevr_mont_mul(out, NR, P, ninv, nl, t, out);
    hevr_one_plus(out, x < 0, P, nl, t);
    hevr_mont_mul(out, acc, P, ninv, nl, t, out); /* y·G^a·R·R^-1: normal form */
}

/* one ciphertext: the two halves and the CRT; L = max(nlp, nlq) limbs of scratch per buffer */
HEVR_HD void hevr_owner_encrypt(long long x, const hevr_u32 *a, int ewa, const hevr_u32 *b, int ewb,
                                const hevr_u32 *Tp, int rows_p, int wp, const hevr_u32 *P2, const hevr_u32 *onep,
                                hevr_u32 ninvp, int nlp, const hevr_u32 *NRp, const hevr_u32 *R2p,
                                const hevr_u32 *Tq, int rows_q, int wq, const hevr_u32 *Q2, const hevr_u32 *oneq,
                                hevr_u32 ninvq, int nlq, const hevr_u32 *NRq, const hevr_u32 *INV, int NL,
                                hevr_u32 *out)
{
    hevr_u32 cp[HEVR_MAX_LIMBS], cq[HEVR_MAX_LIMBS], acc[HEVR_MAX_LIMBS], p2[HEVR_MAX_LIMBS];
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    hevr_owner_half(x, a, ewa, Tp, rows_p, wp, P2, onep, ninvp, nlp, NRp, cp, acc, t);
    hevr_owner_half(x, b, ewb, Tq, rows_q, wq, Q2, oneq, ninvq, nlq, NRq, cq, acc, t);
    /* h = (c_p − c_q)·(q²)^-1 mod p², in Montgomery steps whatever the sizes of p² and q²: c_q·R mod p²
     * by Horner over its limbs, c_p·R by one product, their difference d·R, and d·R·INV·R^-1 = d·INV */
    hevr_reduce_mont(cq, nlq, P2, R2p, ninvp, nlp, acc, p2, t);
    hevr_mont_mul(cp, R2p, P2, ninvp, nlp, t, cp);
    hevr_sub_mod(cp, acc, P2, nlp);
    hevr_mont_mul(cp, INV, P2, ninvp, nlp, t, cp);
    for (int j = 0; j < NL; j++) out[j] = j < nlq ? cq[j] : 0; /* out = c_q + q²·h < n² */
    hevr_mul_add(out, NL, cp, nlp, Q2, nlq);
}

/* ---- public-key encryption ---------------------------------------------------------------------- */

/* out = (1 + x·n)·r^n mod N (N = n², NL limbs; n: k limbs; NR2 = R² mod N): normal form */
HEVR_HD void hevr_public_encrypt(long long x, const hevr_u32 *r, const hevr_u32 *n, int k, const hevr_u32 *N,
                                 const hevr_u32 *one, const hevr_u32 *R2, hevr_u32 ninv, int NL, hevr_u32 *out)
{
    hevr_u32 base[HEVR_MAX_LIMBS], acc[HEVR_MAX_LIMBS], y[HEVR_MAX_LIMBS], t[HEVR_MAX_LIMBS + 2];
    for (int j = 0; j < NL; j++) y[j] = j < k ? r[j] : 0;
    hevr_mont_mul(y, R2, N, ninv, NL, t, base);            /* r·R mod N */
    int top = 0;
    for (int i = 32 * k - 1; i >= 0 && !top; i--) if (n[i >> 5] >> (i & 31) & 1u) top = i + 1;
    for (int j = 0; j < NL; j++) acc[j] = top ? base[j] : one[j];
    for (int i = top - 2; i >= 0; i--) {
        hevr_mont_mul(acc, acc, N, ninv, NL, t, acc);
        if (n[i >> 5] >> (i & 31) & 1u) hevr_mont_mul(acc, base, N, ninv, NL, t, acc);
    }
    hevr_u64 ax = x < 0 ? (hevr_u64)(-(x + 1)) + 1 : (hevr_u64)x;   /* y = |x|·n (< n²), then 1 ± y */
    hevr_u32 xs[2] = {(hevr_u32)ax, (hevr_u32)(ax >> 32)};
    for (int j = 0; j < NL; j++) y[j] = 0;
    hevr_mul_add(y, NL, xs, 2, n, k);
    hevr_one_plus(y, x < 0, N, NL, t);
    hevr_mont_mul(y, acc, N, ninv, NL, t, out);            /* y·r^n·R·R^-1: normal form */
}

/* ---- CRT decryption ---------------------------------------------------------------------------- */

/* one prime: out = L_p((c mod p²)^(p−1) mod p²)·h_p mod p, k limbs (normal form) */
HEVR_HD void hevr_decrypt_half(const hevr_u32 *c, int NL, const hevr_u32 *P2, const hevr_u32 *one2,
                               const hevr_u32 *R2, hevr_u32 ninv2, int nl2, const hevr_u32 *E, int ew,
                               const hevr_u32 *P, const hevr_u32 *PINV, const hevr_u32 *HR, hevr_u32 ninvp, int k,
                               hevr_u32 *out, hevr_u32 *x, hevr_u32 *y, hevr_u32 *t)
{
    hevr_reduce_mont(c, NL, P2, R2, ninv2, nl2, x, y, t);
    int top = 0; /* y = x^E, left-to-right binary, in Montgomery form */
    for (int i = 32 * ew - 1; i >= 0 && !top; i--) if (E[i >> 5] >> (i & 31) & 1u) top = i + 1;
    for (int j = 0; j < nl2; j++) y[j] = top ? x[j] : one2[j];
    for (int i = top - 2; i >= 0; i--) {
        hevr_mont_mul(y, y, P2, ninv2, nl2, t, y);
        if (E[i >> 5] >> (i & 31) & 1u) hevr_mont_mul(y, x, P2, ninv2, nl2, t, y);
    }
    for (int j = 0; j < nl2; j++) x[j] = j == 0;          /* leave Montgomery form: y·1·R^-1 */
    hevr_mont_mul(y, x, P2, ninv2, nl2, t, y);
    hevr_u64 borrow = 1;                                   /* y − 1 (y ≡ 1 mod p, so y >= 1) */
    for (int j = 0; j < nl2; j++) { hevr_u64 d = (hevr_u64)y[j] - borrow; y[j] = (hevr_u32)d; borrow = (d >> 63) & 1; }
    for (int j = 0; j < k; j++) {                          /* L = (y − 1)·p^-1 mod 2^(32k): exact, L < p */
        hevr_u64 cy = 0;
        for (int i = 0; i + j < k; i++) {
            cy += (hevr_u64)y[j] * PINV[i] + (j == 0 ? 0 : out[i + j]);
            out[i + j] = (hevr_u32)cy;
            cy >>= 32;
        }
    }
    hevr_mont_mul(out, HR, P, ninvp, k, t, out);          /* L·h_p mod p (HR = h_p·R mod p) */
}

HEVR_HD void hevr_decrypt(const hevr_u32 *c, int NL,
                          const hevr_u32 *P2, const hevr_u32 *one2p, const hevr_u32 *R2p, hevr_u32 ninv2p, int nl2p,
                          const hevr_u32 *Ep, int ewp, const hevr_u32 *P, const hevr_u32 *PINVp, const hevr_u32 *HRp,
                          hevr_u32 ninvp, int kp,
                          const hevr_u32 *Q2, const hevr_u32 *one2q, const hevr_u32 *R2q, hevr_u32 ninv2q, int nl2q,
                          const hevr_u32 *Eq, int ewq, const hevr_u32 *Q, const hevr_u32 *PINVq, const hevr_u32 *HRq,
                          hevr_u32 ninvq, int kq, const hevr_u32 *R2Q, const hevr_u32 *PIQ, int nlo, hevr_u32 *out)
{
    hevr_u32 mp[HEVR_MAX_LIMBS], mq[HEVR_MAX_LIMBS], x[HEVR_MAX_LIMBS], y[HEVR_MAX_LIMBS];
    hevr_u32 t[HEVR_MAX_LIMBS + 2];
    hevr_decrypt_half(c, NL, P2, one2p, R2p, ninv2p, nl2p, Ep, ewp, P, PINVp, HRp, ninvp, kp, mp, x, y, t);
    hevr_decrypt_half(c, NL, Q2, one2q, R2q, ninv2q, nl2q, Eq, ewq, Q, PINVq, HRq, ninvq, kq, mq, x, y, t);
    /* h = (m_q − m_p)·p^-1 mod q in Montgomery steps (m_p < p may exceed q): m_p·R mod q by Horner,
     * m_q·R by one product, the difference d·R, then d·R·PIQ·R^-1 = d·PIQ */
    hevr_reduce_mont(mp, kp, Q, R2Q, ninvq, kq, x, y, t);
    hevr_mont_mul(mq, R2Q, Q, ninvq, kq, t, mq);
    hevr_sub_mod(mq, x, Q, kq);
    hevr_mont_mul(mq, PIQ, Q, ninvq, kq, t, mq);
    for (int j = 0; j < nlo; j++) out[j] = j < kp ? mp[j] : 0;  /* m = m_p + p·h < n */
    hevr_mul_add(out, nlo, mq, kq, P, kp);
}

#define HEVR_DECRYPT_ARGS const hevr_u32 *c, int NL, \
    const hevr_u32 *P2, const hevr_u32 *one2p, const hevr_u32 *R2p, hevr_u32 ninv2p, int nl2p, const hevr_u32 *Ep, \
    int ewp, const hevr_u32 *P, const hevr_u32 *PINVp, const hevr_u32 *HRp, hevr_u32 ninvp, int kp, \
    const hevr_u32 *Q2, const hevr_u32 *one2q, const hevr_u32 *R2q, hevr_u32 ninv2q, int nl2q, const hevr_u32 *Eq, \
    int ewq, const hevr_u32 *Q, const hevr_u32 *PINVq, const hevr_u32 *HRq, hevr_u32 ninvq, int kq, \
    const hevr_u32 *R2Q, const hevr_u32 *PIQ, int nlo, long long count, hevr_u32 *out
#define HEVR_DECRYPT_CALL(k) hevr_decrypt(c + (k) * NL, NL, P2, one2p, R2p, ninv2p, nl2p, Ep, ewp, P, PINVp, HRp, \
    ninvp, kp, Q2, one2q, R2q, ninv2q, nl2q, Eq, ewq, Q, PINVq, HRq, ninvq, kq, R2Q, PIQ, nlo, out + (k) * nlo)

#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
extern "C" __global__ void k_owner_encrypt(const long long *x, const hevr_u32 *a, int ewa, const hevr_u32 *b,
                                           int ewb, const hevr_u32 *Tp, int rows_p, int wp, const hevr_u32 *P2,
                                           const hevr_u32 *onep, hevr_u32 ninvp, int nlp, const hevr_u32 *NRp,
                                           const hevr_u32 *R2p, const hevr_u32 *Tq, int rows_q, int wq,
                                           const hevr_u32 *Q2, const hevr_u32 *oneq, hevr_u32 ninvq, int nlq,
                                           const hevr_u32 *NRq, const hevr_u32 *INV, int NL, long long count,
                                           hevr_u32 *out)
{
    long long k = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= count) return;
    hevr_owner_encrypt(x[k], a + k * ewa, ewa, b + k * ewb, ewb, Tp, rows_p, wp, P2, onep, ninvp, nlp, NRp, R2p,
                       Tq, rows_q, wq, Q2, oneq, ninvq, nlq, NRq, INV, NL, out + k * NL);
}

extern "C" __global__ void k_public_encrypt(const long long *x, const hevr_u32 *r, const hevr_u32 *n, int k,
                                            const hevr_u32 *N, const hevr_u32 *one, const hevr_u32 *R2,
                                            hevr_u32 ninv, int NL, long long count, hevr_u32 *out)
{
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= count) return;
    hevr_public_encrypt(x[i], r + i * k, n, k, N, one, R2, ninv, NL, out + i * NL);
}

extern "C" __global__ void k_decrypt(HEVR_DECRYPT_ARGS)
{
    long long k = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= count) return;
    HEVR_DECRYPT_CALL(k);
}
#else
int hevr_owner_encrypt_host(const long long *x, const hevr_u32 *a, int ewa, const hevr_u32 *b, int ewb,
                            const hevr_u32 *Tp, int rows_p, int wp, const hevr_u32 *P2, const hevr_u32 *onep,
                            hevr_u32 ninvp, int nlp, const hevr_u32 *NRp, const hevr_u32 *R2p,
                            const hevr_u32 *Tq, int rows_q, int wq, const hevr_u32 *Q2, const hevr_u32 *oneq,
                            hevr_u32 ninvq, int nlq, const hevr_u32 *NRq, const hevr_u32 *INV, int NL,
                            long long count, hevr_u32 *out)
{
    if (nlp < 1 || nlq < 1 || nlp > HEVR_MAX_LIMBS || nlq > HEVR_MAX_LIMBS || NL > HEVR_MAX_LIMBS) return -1;
    for (long long k = 0; k < count; k++)
        hevr_owner_encrypt(x[k], a + k * ewa, ewa, b + k * ewb, ewb, Tp, rows_p, wp, P2, onep, ninvp, nlp, NRp,
                           R2p, Tq, rows_q, wq, Q2, oneq, ninvq, nlq, NRq, INV, NL, out + k * NL);
    return 0;
}

int hevr_public_encrypt_host(const long long *x, const hevr_u32 *r, const hevr_u32 *n, int k, const hevr_u32 *N,
                             const hevr_u32 *one, const hevr_u32 *R2, hevr_u32 ninv, int NL, long long count,
                             hevr_u32 *out)
{
    if (NL > HEVR_MAX_LIMBS || k > NL) return -1;
    for (long long i = 0; i < count; i++)
        hevr_public_encrypt(x[i], r + i * k, n, k, N, one, R2, ninv, NL, out + i * NL);
    return 0;
}

int hevr_decrypt_host(HEVR_DECRYPT_ARGS)
{
    if (nl2p > HEVR_MAX_LIMBS || nl2q > HEVR_MAX_LIMBS || NL > 2 * HEVR_MAX_LIMBS || nlo > HEVR_MAX_LIMBS) return -1;
    for (long long k = 0; k < count; k++) HEVR_DECRYPT_CALL(k);
    return 0;
}
#endif
