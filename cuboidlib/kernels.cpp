// COMPILED VERSION of the hot spots of a CPU training step, loaded by cuboidlib/kernels.py.
//
// Each function does what a labelled piece of Python does, with the same inputs and outputs; the
// tests compare them (tests/test_kernels.py). Mostly the passes over memory change: work that
// PyTorch runs as several elementwise operations, each reading and writing a whole (edges, C)
// tensor, runs here as one loop.
//
// - smallest_k: the top-k selection of cuboidlib.neighbors.knn_indices (torch.topk, largest=False).
// - edge_mlp_forward / edge_mlp_backward: the chunk loops of cuboidlib.edgeconv_fast._EdgeMLP.forward and
//   .backward. The matrix products stay ATen's (at::mm); the gathers, LeakyReLU, the max over
//   neighbours with its argmax, the sums for BatchNorm and the scatters around them are fused. The
//   backward pass also regroups its sums so that it needs two products per chunk instead of three.
// - edge_stats: FastEdgeConv._edge_stats, the first BatchNorm's statistics over all edges.
//
// Scatters (a value added to the row of each edge's neighbour j) are split between threads by
// channel, so no two threads write one entry and the sums come out the same whatever the number of
// threads.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace {

template <typename T>
inline T leaky(T x, T slope) { return x > T(0) ? x : x * slope; }

// NaN sorts after every number, so a row of non-finite values still yields k valid indices.
template <typename T>
inline bool nan_last_less(T x, T y) { return std::isnan(y) ? !std::isnan(x) : x < y; }

// Indices of the k smallest entries of every row of d (R, n; rows may be strided), in no order.
// The k-th smallest of the minima of groups of 16 entries bounds the answer from above (k groups each
// hold an entry at most that small), so only the entries below it, in the groups whose minimum is
// below it, are ranked: about k groups of the n / 16.
template <typename T>
void smallest_k_rows(const T* d, int64_t R, int64_t n, int64_t row_stride, int64_t k, int64_t* out) {
  constexpr int64_t G = 16;
  const int64_t groups = n / G;
  at::parallel_for(0, R, 8, [&](int64_t r0, int64_t r1) {
    std::vector<T> group_min(groups), selection(groups);
    std::vector<int32_t> cand(n);
    for (int64_t r = r0; r < r1; ++r) {
      const T* row = d + r * row_stride;
      T bound = std::numeric_limits<T>::infinity();
      if (groups >= k) {
        for (int64_t g = 0; g < groups; ++g) {
          T m = std::numeric_limits<T>::infinity();
          for (int64_t t = 0; t < G; ++t) {
            const T v = row[g * G + t];
            m = v < m ? v : m;  // NaN never wins
          }
          group_min[g] = m;
        }
        selection = group_min;
        std::nth_element(selection.begin(), selection.begin() + (k - 1), selection.end());
        bound = selection[k - 1];
      }
      int64_t count = 0;
      auto scan = [&](int64_t j0, int64_t j1) {
        for (int64_t j = j0; j < j1; ++j) {
          cand[count] = static_cast<int32_t>(j);
          count += row[j] <= bound;
        }
      };
      for (int64_t g = 0; g < groups; ++g)
        if (group_min[g] <= bound) scan(g * G, (g + 1) * G);
      scan(groups * G, n);  // the entries after the last whole group
      if (count < k) {  // fewer than k finite entries: rank them all
        for (int64_t j = 0; j < n; ++j) cand[j] = static_cast<int32_t>(j);
        count = n;
      }
      std::nth_element(cand.begin(), cand.begin() + (k - 1), cand.begin() + count,
                       [row](int32_t a, int32_t b) { return nan_last_less(row[a], row[b]); });
      for (int64_t i = 0; i < k; ++i) out[r * k + i] = cand[i];
    }
  });
}

// The passes over one chunk's edges. Each is a plain function of pointers and sizes, so that the
// compiler sees that its stores leave its bounds and constants alone, and vectorizes the inner loops.
// Edge e = (i - r0) k + t of a chunk starting at point r0 is the t-th neighbour j = nbr[i k + t] of i.

// out_e = LeakyReLU(z_e), z_e = beta + gamma (P_j + Q_i), for the edges of points [a, b). If positive
// is not null, out_e = LeakyReLU(z_e) - centre instead, and positive_e = (z_e > 0).
template <typename T>
void gather_edges(const T* __restrict__ P, const T* __restrict__ Q, const int64_t* __restrict__ nbr,
                  const T* __restrict__ gamma, const T* __restrict__ beta, T slope, int64_t r0, int64_t a, int64_t b,
                  int64_t k, int64_t C, T* __restrict__ out, const T* __restrict__ centre = nullptr,
                  uint8_t* __restrict__ positive = nullptr) {
  for (int64_t i = a; i < b; ++i) {
    const T* __restrict__ qi = Q + i * C;
    for (int64_t t = 0; t < k; ++t) {
      const T* __restrict__ pj = P + nbr[i * k + t] * C;
      const int64_t e = (i - r0) * k + t;
      T* __restrict__ oe = out + e * C;
      if (positive) {
        uint8_t* __restrict__ pe = positive + e * C;
        for (int64_t c = 0; c < C; ++c) {
          const T z = beta[c] + gamma[c] * (pj[c] + qi[c]);
          oe[c] = leaky(z, slope) - centre[c];
          pe[c] = z > T(0);
        }
      } else {
        for (int64_t c = 0; c < C; ++c) oe[c] = leaky(beta[c] + gamma[c] * (pj[c] + qi[c]), slope);
      }
    }
  }
}

// For points [a, b), with x = h - shift: the max of x over each point's k edges, the index of the edge
// holding it (the last one if several tie), and the sums of x and x^2 over the edges, added to s1
// and s2 in float64. work: 4 C scratch entries.
template <typename T>
void max_and_sums(const T* __restrict__ h, const T* __restrict__ shift, int64_t r0, int64_t a, int64_t b, int64_t k,
                  int64_t C, T* __restrict__ hmax, uint8_t* __restrict__ harg, double* __restrict__ s1,
                  double* __restrict__ s2, T* __restrict__ work) {
  T* __restrict__ best = work;
  T* __restrict__ arg = work + C;
  T* __restrict__ sum1 = work + 2 * C;
  T* __restrict__ sum2 = work + 3 * C;
  for (int64_t i = a; i < b; ++i) {
    const T* __restrict__ h0 = h + (i - r0) * k * C;
    for (int64_t c = 0; c < C; ++c) {
      best[c] = h0[c] - shift[c];
      arg[c] = sum1[c] = sum2[c] = T(0);
    }
    for (int64_t t = 0; t < k; ++t) {
      const T* __restrict__ ht = h0 + t * C;
      const T position = static_cast<T>(t);
      for (int64_t c = 0; c < C; ++c) {
        const T x = ht[c] - shift[c];
        const bool at_least = x >= best[c];
        best[c] = at_least ? x : best[c];
        arg[c] = at_least ? position : arg[c];
        sum1[c] += x;
        sum2[c] += x * x;
      }
    }
    for (int64_t c = 0; c < C; ++c) {
      hmax[i * C + c] = best[c];
      harg[i * C + c] = static_cast<uint8_t>(arg[c]);
      s1[c] += sum1[c];
      s2[c] += sum2[c];
    }
  }
}

// The terms of dL/dhmax, for points [a, b): it reaches h only on the maximising edge e = harg[i, c]
// of each point i and channel c, so gz_e += g_hmax[i, c] W2[c] and dW2[c] += g_hmax[i, c] v_e (the
// caller passes u = v - s as v and adds the sum of g_hmax[., c] s to dW2[c] itself).
template <typename T>
void add_max_terms(T* __restrict__ gz, T* __restrict__ dW2, const T* __restrict__ v, const uint8_t* __restrict__ harg,
                   const T* __restrict__ g_hmax, const T* __restrict__ W2, int64_t r0, int64_t a, int64_t b, int64_t k,
                   int64_t C1, int64_t C2) {
  for (int64_t i = a; i < b; ++i)
    for (int64_t c = 0; c < C2; ++c) {
      const int64_t e = (i - r0) * k + harg[i * C2 + c];
      const T g = g_hmax[i * C2 + c];
      T* __restrict__ ge = gz + e * C1;
      T* __restrict__ dw = dW2 + c * C1;
      const T* __restrict__ w = W2 + c * C1;
      const T* __restrict__ ve = v + e * C1;
      for (int64_t d = 0; d < C1; ++d) {
        ge[d] += g * w[d];
        dw[d] += g * ve[d];
      }
    }
}

// For points [a, b): LeakyReLU backward of g + offset, in place on g (positive: where LeakyReLU's input
// is > 0); the sum of the result over each point's k edges into rowsum; and the sum of u over the
// edges added to usum in float64. work: C scratch entries.
template <typename T>
void leaky_backward_rowsum(T* __restrict__ g, const T* __restrict__ offset, const uint8_t* __restrict__ positive,
                           const T* __restrict__ u, T slope, int64_t r0, int64_t a, int64_t b, int64_t k, int64_t C,
                           T* __restrict__ rowsum, double* __restrict__ usum, T* __restrict__ work) {
  for (int64_t i = a; i < b; ++i) {
    T* __restrict__ rs = rowsum + i * C;
    for (int64_t c = 0; c < C; ++c) rs[c] = work[c] = T(0);
    for (int64_t t = 0; t < k; ++t) {
      const int64_t e = (i - r0) * k + t;
      T* __restrict__ ge = g + e * C;
      const T* __restrict__ ue = u + e * C;
      const uint8_t* __restrict__ pe = positive + e * C;
      for (int64_t c = 0; c < C; ++c) {
        const T y = ge[c] + offset[c];
        const T x = pe[c] ? y : y * slope;
        ge[c] = x;
        rs[c] += x;
        work[c] += ue[c];
      }
    }
    for (int64_t c = 0; c < C; ++c) usum[c] += work[c];
  }
}

// target[j] += value_e over the edges e of points [r0, r1), with value_e = values[e] (rows of an
// (edges, C) tensor), or, if values is null, value_e = P[j] + Q[i] (xhat). Split between threads by
// channel, so no two threads write one entry and the sums do not depend on the number of threads.
template <typename T>
void scatter_edges(const T* values, const T* P, const T* Q, const int64_t* nbr, int64_t r0, int64_t r1, int64_t k,
                   int64_t C, T* target) {
  at::parallel_for(0, C, 16, [=](int64_t c0, int64_t c1) {
    for (int64_t e = r0 * k; e < r1 * k; ++e) {
      const int64_t j = nbr[e];
      T* __restrict__ out = target + j * C;
      if (values) {
        const T* __restrict__ ve = values + (e - r0 * k) * C;
        for (int64_t c = c0; c < c1; ++c) out[c] += ve[c];
      } else {
        const T* __restrict__ pj = P + j * C;
        const T* __restrict__ qi = Q + (e / k) * C;
        for (int64_t c = c0; c < c1; ++c) out[c] += pj[c] + qi[c];
      }
    }
  });
}

template <typename T>
std::vector<torch::Tensor> edge_mlp_forward_impl(const torch::Tensor& P1, const torch::Tensor& Q1,
                                                 const torch::Tensor& nbr, const torch::Tensor& W2,
                                                 const torch::Tensor& shift, double slope, int64_t rows) {
  const int64_t R = P1.size(0), C1 = P1.size(1), k = nbr.size(1), C2 = W2.size(0);
  auto hmax = torch::empty({R, C2}, P1.options());
  auto harg = torch::empty({R, C2}, P1.options().dtype(torch::kUInt8));
  const int64_t threads = at::get_num_threads();
  auto s = torch::zeros({threads, 2, C2}, P1.options().dtype(torch::kDouble));  // per thread: sums of h, h^2
  const auto ones = torch::ones({C1}, P1.options()), zeros = torch::zeros({C1}, P1.options());
  const auto W2T = W2.t();
  // one buffer each for the chunks' v and h, allocated once: fresh memory would cost a page fault
  // per 4 KiB in every chunk
  auto v = torch::empty({rows * k, C1}, P1.options());
  auto h = torch::empty({rows * k, C2}, P1.options());
  for (int64_t r0 = 0; r0 < R; r0 += rows) {
    const int64_t r1 = std::min(R, r0 + rows);
    auto vc = v.narrow(0, 0, (r1 - r0) * k);
    // v = LeakyReLU(P1_j + Q1_i) on every edge (i, j) of the chunk; h = W2 v, reduced as h - shift
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      gather_edges<T>(P1.data_ptr<T>(), Q1.data_ptr<T>(), nbr.data_ptr<int64_t>(), ones.data_ptr<T>(),
                      zeros.data_ptr<T>(), static_cast<T>(slope), r0, a, b, k, C1, vc.data_ptr<T>());
    });
    auto hc = h.narrow(0, 0, (r1 - r0) * k);
    at::mm_out(hc, vc, W2T);
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      std::vector<T> work(4 * C2);
      double* sums = s.data_ptr<double>() + at::get_thread_num() * 2 * C2;
      max_and_sums<T>(hc.data_ptr<T>(), shift.data_ptr<T>(), r0, a, b, k, C2, hmax.data_ptr<T>(),
                      harg.data_ptr<uint8_t>(), sums, sums + C2, work.data());
    });
  }
  const auto total = s.sum(0).to(P1.scalar_type());
  return {hmax, harg, total[0], total[1]};
}

template <typename T>
std::vector<torch::Tensor> edge_mlp_backward_impl(
    const torch::Tensor& P_hat, const torch::Tensor& Q_hat, const torch::Tensor& nbr, const torch::Tensor& gamma1,
    const torch::Tensor& beta1, const torch::Tensor& W2, const torch::Tensor& W2_var, const torch::Tensor& c_mean,
    const torch::Tensor& harg, const torch::Tensor& g_hmax, double slope, int64_t rows, bool batch_stats) {
  const int64_t R = P_hat.size(0), C1 = P_hat.size(1), k = nbr.size(1), C2 = W2.size(0);
  auto g_rowsum = torch::empty_like(Q_hat);
  auto g_scatter = torch::zeros_like(P_hat);
  auto x_scatter = batch_stats ? torch::zeros_like(P_hat) : torch::Tensor();
  // dL/dh = c_mean + c_var h + (dL/dhmax on the maximising edge), h = W2 v. Its products with W2 and v
  // need no h. With u = v - s about a typical value s of v (its value at the BatchNorm mean, so that
  // float32 sums of u u^T lose little) and c = c_mean + c_var W2 s, C = diag(c_var):
  //   dL/dv  = c W2 + u A + (max terms),  A = W2^T C W2;
  //   dL/dW2 = C W2 U + c (sum u)^T + (E c + C W2 sum u + sum_i g_hmax[i]) s^T + (max terms with u),
  //   U = sum of u u^T.
  // Two products per chunk (u A and u^T u) instead of the three of h, dL/dv and dL/dW2.
  const auto s = at::leaky_relu(beta1, slope);
  const auto A = at::mm(W2_var.t(), W2);
  const auto c = c_mean + at::mv(W2_var, s);
  const auto offset = at::mv(W2.t(), c);
  const int64_t threads = at::get_num_threads();
  auto u_sums = torch::zeros({threads, C1}, P_hat.options().dtype(torch::kDouble));
  auto dW2_max = torch::zeros({threads, C2, C1}, P_hat.options());
  auto U = torch::zeros({C1, C1}, P_hat.options());
  auto u = torch::empty({rows * k, C1}, P_hat.options());  // chunk buffers, as in the forward pass
  auto positive = torch::empty({rows * k, C1}, P_hat.options().dtype(torch::kUInt8));
  auto gz_buffer = torch::empty({rows * k, C1}, P_hat.options());
  for (int64_t r0 = 0; r0 < R; r0 += rows) {
    const int64_t r1 = std::min(R, r0 + rows);
    auto uc = u.narrow(0, 0, (r1 - r0) * k);
    // xhat = P_hat_j + Q_hat_i, v = LeakyReLU(gamma1 xhat + beta1), kept as u = v - s and where v > 0
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      gather_edges<T>(P_hat.data_ptr<T>(), Q_hat.data_ptr<T>(), nbr.data_ptr<int64_t>(), gamma1.data_ptr<T>(),
                      beta1.data_ptr<T>(), static_cast<T>(slope), r0, a, b, k, C1, uc.data_ptr<T>(), s.data_ptr<T>(),
                      positive.data_ptr<uint8_t>());
    });
    if (batch_stats)  // the sum of xhat over the edges (., j) ending at each point j
      scatter_edges<T>(nullptr, P_hat.data_ptr<T>(), Q_hat.data_ptr<T>(), nbr.data_ptr<int64_t>(), r0, r1, k, C1,
                       x_scatter.data_ptr<T>());
    U.addmm_(uc.t(), uc);
    auto gz = gz_buffer.narrow(0, 0, (r1 - r0) * k);
    at::mm_out(gz, uc, A);  // dL/dv without c W2 and the max terms; then dL/dz, in place
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      std::vector<T> work(C1);
      add_max_terms<T>(gz.data_ptr<T>(), dW2_max.data_ptr<T>() + at::get_thread_num() * C2 * C1, uc.data_ptr<T>(),
                       harg.data_ptr<uint8_t>(), g_hmax.data_ptr<T>(), W2.data_ptr<T>(), r0, a, b, k, C1, C2);
      leaky_backward_rowsum<T>(gz.data_ptr<T>(), offset.data_ptr<T>(), positive.data_ptr<uint8_t>(), uc.data_ptr<T>(),
                               static_cast<T>(slope), r0, a, b, k, C1, g_rowsum.data_ptr<T>(),
                               u_sums.data_ptr<double>() + at::get_thread_num() * C1, work.data());
    });
    scatter_edges<T>(gz.data_ptr<T>(), nullptr, nullptr, nbr.data_ptr<int64_t>(), r0, r1, k, C1, g_scatter.data_ptr<T>());
  }
  const auto u_sum = u_sums.sum(0).to(P_hat.scalar_type());
  auto g_W2 = at::mm(W2_var, U) + at::outer(c, u_sum) + at::outer(static_cast<double>(R * k) * c + at::mv(W2_var, u_sum) + g_hmax.sum(0), s) +
              dW2_max.sum(0);
  return {g_W2, g_rowsum, g_scatter, x_scatter};
}

// Mean and biased variance over all edges (i, j) of u = P_j + Q_i, summed per point in float64
// without storing any float64 (R, C) tensor (FastEdgeConv._edge_stats, whose docstring derives them).
// Returns (2, C): the mean, then the variance.
template <typename T>
torch::Tensor edge_stats_impl(const torch::Tensor& P, const torch::Tensor& Q, const torch::Tensor& nbr,
                              const torch::Tensor& in_degree) {
  const int64_t R = P.size(0), C = P.size(1), k = nbr.size(1);
  const int64_t threads = at::get_num_threads();
  const double edges = static_cast<double>(R * k);
  auto sums = torch::zeros({threads, C}, P.options().dtype(torch::kDouble));
  const T* p = P.data_ptr<T>();
  const T* q = Q.data_ptr<T>();
  const int64_t* nb = nbr.data_ptr<int64_t>();
  const int64_t* deg = in_degree.data_ptr<int64_t>();
  // sum over edges of u = sum_j indegree_j P_j + k sum_i Q_i
  at::parallel_for(0, R, 256, [&](int64_t a, int64_t b) {
    double* __restrict__ out = sums.data_ptr<double>() + at::get_thread_num() * C;
    for (int64_t i = a; i < b; ++i) {
      const double d = static_cast<double>(deg[i]);
      for (int64_t c = 0; c < C; ++c)
        out[c] += d * static_cast<double>(p[i * C + c]) + static_cast<double>(k) * static_cast<double>(q[i * C + c]);
    }
  });
  const auto mean = sums.sum(0) / edges;
  sums.zero_();
  // sum over edges of (u - mean)^2 = sum_j indegree_j P_j^2 + sum_i (k Qc_i^2 + 2 Qc_i S_i), Qc = Q - mean
  at::parallel_for(0, R, 64, [&](int64_t a, int64_t b) {
    std::vector<double> S(C);
    double* __restrict__ sp = S.data();
    double* __restrict__ out = sums.data_ptr<double>() + at::get_thread_num() * C;
    const double* __restrict__ mu = mean.data_ptr<double>();
    for (int64_t i = a; i < b; ++i) {
      for (int64_t c = 0; c < C; ++c) sp[c] = 0.0;
      for (int64_t t = 0; t < k; ++t) {
        const T* __restrict__ pj = p + nb[i * k + t] * C;
        for (int64_t c = 0; c < C; ++c) sp[c] += static_cast<double>(pj[c]);
      }
      const double d = static_cast<double>(deg[i]);
      for (int64_t c = 0; c < C; ++c) {
        const double pc = static_cast<double>(p[i * C + c]), qc = static_cast<double>(q[i * C + c]) - mu[c];
        out[c] += d * pc * pc + static_cast<double>(k) * qc * qc + 2.0 * qc * sp[c];
      }
    }
  });
  const auto var = (sums.sum(0) / edges).clamp_min(0);
  return torch::stack({mean, var});
}

void check_cpu_contiguous(const torch::Tensor& t, const char* name) {
  TORCH_CHECK(t.device().is_cpu() && t.is_contiguous(), name, " must be a contiguous CPU tensor");
}

}  // namespace

torch::Tensor smallest_k(const torch::Tensor& d, int64_t k) {
  TORCH_CHECK(d.dim() == 2 && d.device().is_cpu() && d.stride(1) == 1, "d must be a (R, n) CPU tensor with unit column stride");
  TORCH_CHECK(k >= 1 && k <= d.size(1), "k must be in [1, n]");
  auto out = torch::empty({d.size(0), k}, d.options().dtype(torch::kLong));
  AT_DISPATCH_FLOATING_TYPES(d.scalar_type(), "smallest_k", [&] {
    smallest_k_rows<scalar_t>(d.data_ptr<scalar_t>(), d.size(0), d.size(1), d.stride(0), k, out.data_ptr<int64_t>());
  });
  return out;
}

std::vector<torch::Tensor> edge_mlp_forward(const torch::Tensor& P1, const torch::Tensor& Q1, const torch::Tensor& nbr,
                                            const torch::Tensor& W2, const torch::Tensor& shift, double slope, int64_t rows) {
  for (auto& [t, name] : {std::pair{P1, "P1"}, {Q1, "Q1"}, {nbr, "nbr"}, {W2, "W2"}, {shift, "shift"}})
    check_cpu_contiguous(t, name);
  TORCH_CHECK(nbr.size(1) <= 256, "at most 256 neighbours");
  std::vector<torch::Tensor> out;
  AT_DISPATCH_FLOATING_TYPES(P1.scalar_type(), "edge_mlp_forward", [&] {
    out = edge_mlp_forward_impl<scalar_t>(P1, Q1, nbr, W2, shift, slope, rows);
  });
  return out;
}

std::vector<torch::Tensor> edge_mlp_backward(const torch::Tensor& P_hat, const torch::Tensor& Q_hat,
                                             const torch::Tensor& nbr, const torch::Tensor& gamma1,
                                             const torch::Tensor& beta1, const torch::Tensor& W2,
                                             const torch::Tensor& W2_var, const torch::Tensor& c_mean,
                                             const torch::Tensor& harg, const torch::Tensor& g_hmax, double slope,
                                             int64_t rows, bool batch_stats) {
  for (auto& [t, name] : {std::pair{P_hat, "P_hat"}, {Q_hat, "Q_hat"}, {nbr, "nbr"}, {gamma1, "gamma1"},
                          {beta1, "beta1"}, {W2, "W2"}, {W2_var, "W2_var"}, {c_mean, "c_mean"}, {harg, "harg"},
                          {g_hmax, "g_hmax"}})
    check_cpu_contiguous(t, name);
  TORCH_CHECK(harg.scalar_type() == torch::kUInt8, "harg must be uint8");
  std::vector<torch::Tensor> out;
  AT_DISPATCH_FLOATING_TYPES(P_hat.scalar_type(), "edge_mlp_backward", [&] {
    out = edge_mlp_backward_impl<scalar_t>(P_hat, Q_hat, nbr, gamma1, beta1, W2, W2_var, c_mean, harg, g_hmax, slope,
                                           rows, batch_stats);
  });
  return out;
}

torch::Tensor edge_stats(const torch::Tensor& P, const torch::Tensor& Q, const torch::Tensor& nbr,
                         const torch::Tensor& in_degree) {
  for (auto& [t, name] : {std::pair{P, "P"}, {Q, "Q"}, {nbr, "nbr"}, {in_degree, "in_degree"}}) check_cpu_contiguous(t, name);
  TORCH_CHECK(in_degree.scalar_type() == torch::kLong, "in_degree must be int64");
  torch::Tensor out;
  AT_DISPATCH_FLOATING_TYPES(P.scalar_type(), "edge_stats", [&] { out = edge_stats_impl<scalar_t>(P, Q, nbr, in_degree); });
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("smallest_k", &smallest_k, "indices of the k smallest entries of each row, unordered");
  m.def("edge_stats", &edge_stats, "FastEdgeConv._edge_stats: (mean, variance) of u over all edges");
  m.def("edge_mlp_forward", &edge_mlp_forward, "chunk loop of _EdgeMLP.forward");
  m.def("edge_mlp_backward", &edge_mlp_backward, "chunk loop of _EdgeMLP.backward");
}
