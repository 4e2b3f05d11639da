// COMPILED VERSION of two hot spots of a CPU training step, loaded by cuboidlib/kernels.py.
//
// Each function does what a labelled piece of Python does, with the same inputs and outputs; the
// tests compare them (tests/test_kernels.py). Only the passes over memory change: work that PyTorch
// runs as several elementwise operations, each reading and writing a whole (edges, C) tensor, runs
// here as one loop.
//
// - smallest_k: the top-k selection of cuboidlib.neighbors.knn_indices (torch.topk, largest=False).
// - edge_mlp_forward / edge_mlp_backward: the chunk loops of cuboidlib.model._EdgeMLP.forward and
//   .backward. The matrix products stay ATen's (at::addmm, at::mm); the gathers, LeakyReLU, the max
//   over neighbours with its argmax, the sums for BatchNorm and the scatters around them are fused.
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
// hold an entry at most that small), so only the few entries below it are ranked.
template <typename T>
void smallest_k_rows(const T* d, int64_t R, int64_t n, int64_t row_stride, int64_t k, int64_t* out) {
  constexpr int64_t G = 16;
  const int64_t groups = n / G;
  at::parallel_for(0, R, 8, [&](int64_t r0, int64_t r1) {
    std::vector<T> group_min(groups);
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
        std::nth_element(group_min.begin(), group_min.begin() + (k - 1), group_min.end());
        bound = group_min[k - 1];
      }
      int64_t count = 0;
      for (int64_t j = 0; j < n; ++j) {
        cand[count] = static_cast<int32_t>(j);
        count += row[j] <= bound;
      }
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

// out_e = LeakyReLU(beta + gamma (P_j + Q_i)) for the edges of points [a, b).
template <typename T>
void gather_edges(const T* __restrict__ P, const T* __restrict__ Q, const int64_t* __restrict__ nbr,
                  const T* __restrict__ gamma, const T* __restrict__ beta, T slope, int64_t r0, int64_t a, int64_t b,
                  int64_t k, int64_t C, T* __restrict__ out) {
  for (int64_t i = a; i < b; ++i) {
    const T* __restrict__ qi = Q + i * C;
    for (int64_t t = 0; t < k; ++t) {
      const T* __restrict__ pj = P + nbr[i * k + t] * C;
      T* __restrict__ oe = out + ((i - r0) * k + t) * C;
      for (int64_t c = 0; c < C; ++c) oe[c] = leaky(beta[c] + gamma[c] * (pj[c] + qi[c]), slope);
    }
  }
}

// For points [a, b): the max of h over each point's k edges, the index of the edge holding it (the
// last one if several tie), and the sums of h and h^2 over the edges, added to s1 and s2 in float64.
// work: 4 C scratch entries.
template <typename T>
void max_and_sums(const T* __restrict__ h, int64_t r0, int64_t a, int64_t b, int64_t k, int64_t C, T* __restrict__ hmax,
                  uint8_t* __restrict__ harg, double* __restrict__ s1, double* __restrict__ s2, T* __restrict__ work) {
  T* __restrict__ best = work;
  T* __restrict__ arg = work + C;
  T* __restrict__ sum1 = work + 2 * C;
  T* __restrict__ sum2 = work + 3 * C;
  for (int64_t i = a; i < b; ++i) {
    const T* __restrict__ h0 = h + (i - r0) * k * C;
    for (int64_t c = 0; c < C; ++c) {
      best[c] = h0[c];
      arg[c] = sum1[c] = sum2[c] = T(0);
    }
    for (int64_t t = 0; t < k; ++t) {
      const T* __restrict__ ht = h0 + t * C;
      const T position = static_cast<T>(t);
      for (int64_t c = 0; c < C; ++c) {
        const T x = ht[c];
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

// gh on the edge harg[i, c] of point i, channel c += g_hmax[i, c], for points [a, b).
template <typename T>
void add_at_max(T* __restrict__ gh, const uint8_t* __restrict__ harg, const T* __restrict__ g_hmax, int64_t r0, int64_t a,
                int64_t b, int64_t k, int64_t C) {
  for (int64_t i = a; i < b; ++i)
    for (int64_t c = 0; c < C; ++c) gh[((i - r0) * k + harg[i * C + c]) * C + c] += g_hmax[i * C + c];
}

// LeakyReLU backward from its output v (v > 0 exactly where its input is), in place on g, and the
// sum of the result over each point's k edges into rowsum, for points [a, b).
template <typename T>
void leaky_backward_rowsum(T* __restrict__ g, const T* __restrict__ v, T slope, int64_t r0, int64_t a, int64_t b,
                           int64_t k, int64_t C, T* __restrict__ rowsum) {
  for (int64_t i = a; i < b; ++i) {
    T* __restrict__ rs = rowsum + i * C;
    for (int64_t c = 0; c < C; ++c) rs[c] = T(0);
    for (int64_t t = 0; t < k; ++t) {
      const int64_t e = (i - r0) * k + t;
      T* __restrict__ ge = g + e * C;
      const T* __restrict__ ve = v + e * C;
      for (int64_t c = 0; c < C; ++c) {
        const T x = ve[c] > T(0) ? ge[c] : ge[c] * slope;
        ge[c] = x;
        rs[c] += x;
      }
    }
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
  const auto minus_shift = -shift;
  auto v = torch::empty({rows * k, C1}, P1.options());
  for (int64_t r0 = 0; r0 < R; r0 += rows) {
    const int64_t r1 = std::min(R, r0 + rows);
    auto vc = v.narrow(0, 0, (r1 - r0) * k);
    // v = LeakyReLU(P1_j + Q1_i) on every edge (i, j) of the chunk; then h - shift = W2 v - shift
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      gather_edges<T>(P1.data_ptr<T>(), Q1.data_ptr<T>(), nbr.data_ptr<int64_t>(), ones.data_ptr<T>(),
                      zeros.data_ptr<T>(), static_cast<T>(slope), r0, a, b, k, C1, vc.data_ptr<T>());
    });
    const auto hc = at::addmm(minus_shift, vc, W2T);
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      std::vector<T> work(4 * C2);
      double* sums = s.data_ptr<double>() + at::get_thread_num() * 2 * C2;
      max_and_sums<T>(hc.data_ptr<T>(), r0, a, b, k, C2, hmax.data_ptr<T>(), harg.data_ptr<uint8_t>(), sums, sums + C2,
                      work.data());
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
  auto g_W2 = torch::zeros_like(W2);
  auto g_rowsum = torch::empty_like(Q_hat);
  auto g_scatter = torch::zeros_like(P_hat);
  auto x_scatter = batch_stats ? torch::zeros_like(P_hat) : torch::Tensor();
  const auto W2_varT = W2_var.t();
  auto v = torch::empty({rows * k, C1}, P_hat.options());
  for (int64_t r0 = 0; r0 < R; r0 += rows) {
    const int64_t r1 = std::min(R, r0 + rows);
    auto vc = v.narrow(0, 0, (r1 - r0) * k);
    // xhat = P_hat_j + Q_hat_i, v = LeakyReLU(gamma1 xhat + beta1)
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      gather_edges<T>(P_hat.data_ptr<T>(), Q_hat.data_ptr<T>(), nbr.data_ptr<int64_t>(), gamma1.data_ptr<T>(),
                      beta1.data_ptr<T>(), static_cast<T>(slope), r0, a, b, k, C1, vc.data_ptr<T>());
    });
    if (batch_stats)  // the sum of xhat over the edges (., j) ending at each point j
      scatter_edges<T>(nullptr, P_hat.data_ptr<T>(), Q_hat.data_ptr<T>(), nbr.data_ptr<int64_t>(), r0, r1, k, C1,
                       x_scatter.data_ptr<T>());
    // dL/dh = c_mean + c_var h, plus dL/dhmax on the maximising edge
    auto gh = at::addmm(c_mean, vc, W2_varT);
    at::parallel_for(r0, r1, 64, [&](int64_t a, int64_t b) {
      add_at_max<T>(gh.data_ptr<T>(), harg.data_ptr<uint8_t>(), g_hmax.data_ptr<T>(), r0, a, b, k, C2);
    });
    g_W2.addmm_(gh.t(), vc);
    auto gz = at::mm(gh, W2);  // dL/dv, then dL/dz in place
    at::parallel_for(r0, r1, 16, [&](int64_t a, int64_t b) {
      leaky_backward_rowsum<T>(gz.data_ptr<T>(), vc.data_ptr<T>(), static_cast<T>(slope), r0, a, b, k, C1,
                               g_rowsum.data_ptr<T>());
    });
    scatter_edges<T>(gz.data_ptr<T>(), nullptr, nullptr, nbr.data_ptr<int64_t>(), r0, r1, k, C1, g_scatter.data_ptr<T>());
  }
  return {g_W2, g_rowsum, g_scatter, x_scatter};
}

// sum over points i of (Q_i - mean) * S_i, S_i = the sum of P_j over the neighbours j of i, in float64
// (the cross term of FastEdgeConv._edge_stats).
template <typename T>
torch::Tensor edge_cross_impl(const torch::Tensor& P, const torch::Tensor& Q, const torch::Tensor& mean,
                              const torch::Tensor& nbr) {
  const int64_t R = P.size(0), C = P.size(1), k = nbr.size(1);
  const int64_t threads = at::get_num_threads();
  auto partial = torch::zeros({threads, C}, mean.options());
  at::parallel_for(0, R, 64, [&](int64_t a, int64_t b) {
    std::vector<double> S(C);
    double* __restrict__ sp = S.data();
    double* __restrict__ out = partial.data_ptr<double>() + at::get_thread_num() * C;
    const double* __restrict__ mu = mean.data_ptr<double>();
    const T* __restrict__ p = P.data_ptr<T>();
    const T* __restrict__ q = Q.data_ptr<T>();
    const int64_t* __restrict__ nb = nbr.data_ptr<int64_t>();
    for (int64_t i = a; i < b; ++i) {
      for (int64_t c = 0; c < C; ++c) sp[c] = 0.0;
      for (int64_t t = 0; t < k; ++t) {
        const T* __restrict__ pj = p + nb[i * k + t] * C;
        for (int64_t c = 0; c < C; ++c) sp[c] += static_cast<double>(pj[c]);
      }
      for (int64_t c = 0; c < C; ++c) out[c] += (static_cast<double>(q[i * C + c]) - mu[c]) * sp[c];
    }
  });
  return partial.sum(0);
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

torch::Tensor edge_cross(const torch::Tensor& P, const torch::Tensor& Q, const torch::Tensor& mean, const torch::Tensor& nbr) {
  for (auto& [t, name] : {std::pair{P, "P"}, {Q, "Q"}, {mean, "mean"}, {nbr, "nbr"}}) check_cpu_contiguous(t, name);
  TORCH_CHECK(mean.scalar_type() == torch::kDouble, "mean must be float64");
  torch::Tensor out;
  AT_DISPATCH_FLOATING_TYPES(P.scalar_type(), "edge_cross", [&] { out = edge_cross_impl<scalar_t>(P, Q, mean, nbr); });
  return out;
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("smallest_k", &smallest_k, "indices of the k smallest entries of each row, unordered");
  m.def("edge_cross", &edge_cross, "cross term of FastEdgeConv._edge_stats");
  m.def("edge_mlp_forward", &edge_mlp_forward, "chunk loop of _EdgeMLP.forward");
  m.def("edge_mlp_backward", &edge_mlp_backward, "chunk loop of _EdgeMLP.backward");
}
