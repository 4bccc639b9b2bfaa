#include "core/net/fec.h"

#include "core/base/error.h"

#include <isa-l/erasure_code.h>

#include <algorithm>
#include <cmath>

namespace dhr {

bool fec_layout(int data, int parity, FecLayout& out) {
  if (data < 1 || parity < 0 || data + parity > 65535) return false;
  out = {};
  out.data = data;
  out.parity = parity;
  out.blocks = (data + kFecMaxBlockData - 1) / kFecMaxBlockData;
  if (parity == 0) return true;
  if (parity % out.blocks != 0) return false;
  out.per_block = parity / out.blocks;
  return out.block_data(0) + out.per_block <= kFecMaxShards;  // block 0 is the largest
}

int fec_parity_count(int data, double fraction, int min_parity) {
  if (!(fraction >= 0.0 && fraction <= 1.0)) fail("fec: parity fraction {} out of range 0..1", fraction);
  if (min_parity < 0 || min_parity >= kFecMaxShards)
    fail("fec: min_parity {} out of range 0..{}", min_parity, kFecMaxShards - 1);
  if (data < 1 || (fraction == 0.0 && min_parity == 0)) return 0;
  FecLayout l;
  fec_layout(data, 0, l);
  const int k = l.block_data(0);
  // ceil of fraction * k, robust to the rounding of fraction (0.2 * 10 is 2, not 3).
  const int by_fraction = int(std::ceil(fraction * k - 1e-9));
  const int m = std::min(std::max(min_parity, by_fraction), kFecMaxShards - k);
  return std::min(m * l.blocks, 65535 - data);
}

bool fec_blocks_complete(const FecLayout& l, std::span<const uint16_t> block_have) {
  if (block_have.size() != size_t(l.blocks)) return false;
  for (int b = 0; b < l.blocks; ++b)
    if (block_have[size_t(b)] < l.block_data(b)) return false;
  return true;
}

bool fec_can_rebuild(const FecLayout& l, const std::vector<bool>& arrived) {
  if (arrived.size() != size_t(l.data + l.parity)) return false;
  std::vector<uint16_t> have(size_t(l.blocks), 0);
  for (int i = 0; i < l.data + l.parity; ++i)
    if (arrived[size_t(i)]) ++have[size_t(l.block_of(i))];
  return fec_blocks_complete(l, have);
}

namespace {

std::vector<uint8_t> cauchy(int k, int m) {
  std::vector<uint8_t> a(size_t(k + m) * size_t(k));
  gf_gen_cauchy1_matrix(a.data(), k + m, k);
  return a;
}

}  // namespace

void rs_encode(int k, int m, size_t len, const uint8_t* const* data, uint8_t* const* parity) {
  if (k < 1 || m < 1 || k + m > kFecMaxShards) fail("rs_encode: {} data and {} parity shards", k, m);
  if (len == 0) return;
  const std::vector<uint8_t> a = cauchy(k, m);
  std::vector<uint8_t> tables(size_t(k) * size_t(m) * 32);
  ec_init_tables(k, m, const_cast<uint8_t*>(a.data() + size_t(k) * size_t(k)), tables.data());
  ec_encode_data(int(len), k, m, tables.data(), const_cast<uint8_t**>(data), const_cast<uint8_t**>(parity));
}

bool rs_decode(int k, int m, size_t len, std::span<const int> present, const uint8_t* const* shards,
               std::span<const int> missing, uint8_t* const* out) {
  if (k < 1 || m < 0 || k + m > kFecMaxShards || present.size() != size_t(k)) return false;
  if (missing.empty()) return true;
  // The code is systematic: the present data shards are themselves, so only the r missing data
  // shards are unknown, and r present parity rows give r equations in them. With C the parity
  // rows of the Cauchy matrix: C[M] d[M] = p - C[P] d[P] (minus is plus in GF(2^8)), so
  // d[M] = C[M]^-1 p + (C[M]^-1 C[P]) d[P]: an r x r inverse instead of k x k.
  const size_t r = missing.size();
  const std::vector<uint8_t> a = cauchy(k, std::max(m, 1));
  std::vector<int> col(size_t(k), -1);  // data shard -> its column among the present shards
  std::vector<int> parity_rows, parity_cols;
  for (size_t c = 0; c < present.size(); ++c) {
    const int s = present[c];
    if (s < 0 || s >= k + m) return false;
    if (s < k) {
      if (col[size_t(s)] >= 0) return false;
      col[size_t(s)] = int(c);
    } else {
      parity_rows.push_back(s);
      parity_cols.push_back(int(c));
    }
  }
  if (parity_rows.size() != r) return false;  // k present shards, r of the data missing
  for (const int i : missing)
    if (i < 0 || i >= k || col[size_t(i)] >= 0) return false;
  std::vector<uint8_t> cm(r * r), inv(r * r);
  for (size_t j = 0; j < r; ++j)
    for (size_t q = 0; q < r; ++q) cm[j * r + q] = a[size_t(parity_rows[j]) * size_t(k) + size_t(missing[q])];
  if (gf_invert_matrix(cm.data(), inv.data(), int(r)) != 0) return false;
  // Row q of the decode matrix, over the k present shards in their order.
  std::vector<uint8_t> rows(r * size_t(k), 0);
  for (size_t q = 0; q < r; ++q) {
    uint8_t* row = rows.data() + q * size_t(k);
    for (size_t j = 0; j < r; ++j) row[parity_cols[j]] = inv[q * r + j];
    for (int i = 0; i < k; ++i) {
      if (col[size_t(i)] < 0) continue;
      uint8_t v = 0;
      for (size_t j = 0; j < r; ++j) v ^= gf_mul(inv[q * r + j], a[size_t(parity_rows[j]) * size_t(k) + size_t(i)]);
      row[col[size_t(i)]] = v;
    }
  }
  if (len == 0) return true;
  std::vector<uint8_t> tables(size_t(k) * r * 32);
  ec_init_tables(k, int(r), rows.data(), tables.data());
  ec_encode_data(int(len), k, int(r), tables.data(), const_cast<uint8_t**>(shards), const_cast<uint8_t**>(out));
  return true;
}

}  // namespace dhr
