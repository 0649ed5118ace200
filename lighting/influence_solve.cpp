// Solving for D = B - B~ (lighting/influence.h): propagation by shooting the unshot differences
// (Southwell iteration on a hierarchy: each element's unshot difference goes through the links
// that leave it, the receivers' gathers are pushed to their leaves and pulled back up), and the
// plain Jacobi sweeps of the same system that the tests and the from-scratch path use.
//
// Invariant between rounds: every receiver has gathered w (D_s - U_s) from each source s (U the
// difference not yet shot), every leaf holds its equation's value for what it has gathered, and
// every element above the leaves the pulled mean of its children. At the end no |U| exceeds
// residual x the largest radiance: that is the error bound the tests compare against.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "lighting/influence_impl.h"

namespace commonlight::lighting {

namespace {
constexpr double kPi = std::numbers::pi;

// addUnshot() with its bound `tau` (residual x scale) given, inlined where the propagation calls
// it (a million calls per second of moves: the call itself cost a third of it). `D`: the Impl.
template <class D>
inline void addUnshotWith(D& d, int element, const Eigen::Vector3d& delta, double tau) {
    const auto e = static_cast<std::size_t>(element);
    if (d.sub[e]) return;  // elements made here send no link: their difference goes up to their base leaf
    d.U[e] += delta;
    if (!d.queued[e] && d.U[e].cwiseAbs().maxCoeff() > tau) {
        d.queued[e] = 1;
        d.worklist.push_back(element);
    }
}
}  // namespace

Eigen::Vector3d VirtualInfluence::Impl::value(int leaf) const {
    const Hierarchy& h = self.radiosity_.hierarchy();
    const LeafTerms& t = terms[static_cast<std::size_t>(leaf)];
    Eigen::Vector3d irradiance = Eigen::Vector3d::Zero();
    if (has_terms[static_cast<std::size_t>(leaf)]) irradiance += t.direct + t.cluster;
    for (int a = leaf; a >= 0; a = h[a].parent) {
        const auto i = static_cast<std::size_t>(a);
        irradiance += G[i] + V[i];
        if (has_terms[i]) irradiance += terms[i].cl;
    }
    return self.rho_[static_cast<std::size_t>(leaf)].cwiseProduct(irradiance) / kPi;
}

void VirtualInfluence::Impl::addUnshot(int element, const Eigen::Vector3d& delta) {
    addUnshotWith(*this, element, delta, self.options_.residual * scale);
}

// Adds irradiance to everything an element gathers: every leaf under it changes by rho / pi of it;
// returns the element's pulled change (its parents' are the caller's: propagateUp()).
Eigen::Vector3d VirtualInfluence::Impl::pushDown(int element, const Eigen::Vector3d& irradiance) {
    const Element* els = self.radiosity_.hierarchy().elements().data();
    return pushDownIn(els, element, irradiance, self.options_.residual * scale, 1e-6 * scale);
}

// pushDown() with the elements and the two bounds found once for the whole subtree (the same
// arithmetic in the same order).
Eigen::Vector3d VirtualInfluence::Impl::pushDownIn(const Element* els, int element, const Eigen::Vector3d& irradiance, double tau,
                                                   double dirty) {
    const Element& el = els[element];
    const auto e = static_cast<std::size_t>(element);
    if (el.buried) return Eigen::Vector3d::Zero();
    Eigen::Vector3d delta = Eigen::Vector3d::Zero();
    if (el.child_count == 0) {
        delta = self.rho_[e].cwiseProduct(irradiance) / kPi;
    } else {
        const int first = el.first_child, count = el.child_count;
        for (int c = 0; c < count; ++c) delta += up[static_cast<std::size_t>(first + c)] * pushDownIn(els, first + c, irradiance, tau, dirty);
    }
    self.d_[e] += delta;
    if (delta.cwiseAbs().maxCoeff() > dirty) face_dirty[static_cast<std::size_t>(el.face)] = 1;
    addUnshotWith(*this, element, delta, tau);
    return delta;
}

void VirtualInfluence::Impl::propagateUp(int element, Eigen::Vector3d delta) {
    if (delta.isZero()) return;
    // (The elements and the differences read through local pointers, not reloaded at every level.)
    const Element* els = self.radiosity_.hierarchy().elements().data();
    const double* w = up.data();
    Eigen::Vector3d* d = self.d_.data();
    const double tau = self.options_.residual * scale;
    for (int e = element, p = els[element].parent; p >= 0; e = p, p = els[p].parent) {
        delta *= w[e];
        d[static_cast<std::size_t>(p)] += delta;
        addUnshotWith(*this, p, delta, tau);
    }
}

// Pulls D up inside an element's subtree (its leaves' values set), the element included.
void VirtualInfluence::Impl::pullSubtree(int element) {
    const Hierarchy& h = self.radiosity_.hierarchy();
    const Element& el = h[element];
    if (el.child_count == 0) return;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int c = 0; c < el.child_count; ++c) {
        pullSubtree(el.first_child + c);
        sum += up[static_cast<std::size_t>(el.first_child + c)] * self.d_[static_cast<std::size_t>(el.first_child + c)];
    }
    self.d_[static_cast<std::size_t>(element)] = sum;
}

void VirtualInfluence::Impl::propagate(InfluenceStats& stats) {
    const double tau = self.options_.residual * scale;
    int rounds = 0;
    while (!worklist.empty() && rounds < 100000) {
        ++rounds;
        std::vector<int> list;
        list.swap(worklist);
        for (int e : list) queued[static_cast<std::size_t>(e)] = 0;
        // Step 1: shoot every element whose unshot difference exceeds the bound.
        for (int e : list) {
            const auto i = static_cast<std::size_t>(e);
            const Eigen::Vector3d u = U[i];
            if (!(u.cwiseAbs().maxCoeff() > tau)) continue;  // below the bound: stays unshot
            U[i].setZero();
            ++shots;
            for (int k = link_offsets[i]; k < link_offsets[i + 1]; ++k) {
                const Link& l = links[static_cast<std::size_t>(link_by_source[static_cast<std::size_t>(k)])];
                const Eigen::Vector3d dg = (kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real)) * u;
                const auto r = static_cast<std::size_t>(l.receiver);
                G[r] += dg;
                pending[r] += dg;
                if (!pending_flag[r]) {
                    pending_flag[r] = 1;
                    pending_list.push_back(l.receiver);
                }
            }
            if (i + 1 < corr_offsets.size()) {
                for (int k = corr_offsets[i]; k < corr_offsets[i + 1]; ++k) {
                    const auto [leaf, k_corr] = corr_by_source[static_cast<std::size_t>(k)];  // the receiver: any element
                    LeafTerms& t = terms[static_cast<std::size_t>(leaf)];
                    const Eigen::Vector3d dc = t.corrections[static_cast<std::size_t>(k_corr)].coef * u;
                    t.cl += dc;
                    const auto c = static_cast<std::size_t>(leaf);
                    pending[c] += dc;
                    if (!pending_flag[c]) {
                        pending_flag[c] = 1;
                        pending_list.push_back(leaf);
                    }
                }
            }
        }
        // Step 2: what the receivers gathered, down to their leaves and back up.
        std::vector<int> receivers;
        receivers.swap(pending_list);
        for (int r : receivers) {
            const auto i = static_cast<std::size_t>(r);
            const Eigen::Vector3d irradiance = pending[i];
            pending[i].setZero();
            pending_flag[i] = 0;
            propagateUp(r, pushDown(r, irradiance));
        }
    }
    double left = 0.0;
    for (const Eigen::Vector3d& u : U) left = std::max(left, u.cwiseAbs().maxCoeff());
    stats.rounds = rounds;
    stats.shots = shots;
    stats.residual = left / scale;
}

std::vector<Eigen::Vector3d> VirtualInfluence::denseDifference(double tolerance) const {
    const Impl& d = *impl_;
    const Hierarchy& h = radiosity_.hierarchy();
    const std::size_t n = h.elements().size();
    const std::vector<Link>& links = d.links;
    std::vector<Eigen::Vector3d> D(n, Eigen::Vector3d::Zero()), G(n);
    std::vector<int> leaves;
    for (int e : radiosity_.leaves(Mode::kReal)) leaves.push_back(e);
    const auto pull = [&]() {
        // Children have larger indices than their parents: one backward sweep.
        for (std::size_t i = n; i-- > 0;) {
            const Element& el = h[static_cast<int>(i)];
            if (el.child_count == 0 || radiosity_.isVirtualFace(el.face)) continue;
            Eigen::Vector3d sum = Eigen::Vector3d::Zero();
            for (int c = 0; c < el.child_count; ++c) sum += d.up[static_cast<std::size_t>(el.first_child + c)] * D[static_cast<std::size_t>(el.first_child + c)];
            D[i] = sum;
        }
    };
    std::vector<int> receivers;  // elements with corrections
    for (std::size_t i = 0; i < n && i < d.has_terms.size(); ++i) {
        if (d.has_terms[i] && !h[static_cast<int>(i)].retired && !d.terms[i].corrections.empty()) receivers.push_back(static_cast<int>(i));
    }
    for (int iteration = 0; iteration < 5000; ++iteration) {
        // Step 1: gathers from the current differences: base links and corrections.
        std::fill(G.begin(), G.end(), Eigen::Vector3d::Zero());
        for (const Link& l : links) {
            G[static_cast<std::size_t>(l.receiver)] +=
                (kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real)) * D[static_cast<std::size_t>(l.source)];
        }
        for (int r : receivers) {
            for (const Correction& corr : d.terms[static_cast<std::size_t>(r)].corrections) {
                const auto s = static_cast<std::size_t>(corr.source);
                G[static_cast<std::size_t>(r)] += corr.coef * (d.base.radiance[s] + D[s]);
            }
        }
        // Step 2: every leaf's equation.
        double change = 0.0;
        std::vector<Eigen::Vector3d> next(leaves.size());
        for (std::size_t k = 0; k < leaves.size(); ++k) {
            const int c = leaves[k];
            const auto i = static_cast<std::size_t>(c);
            if (h[c].buried) {
                next[k].setZero();
                continue;
            }
            const LeafTerms& t = d.terms[i];
            Eigen::Vector3d irradiance = Eigen::Vector3d::Zero();
            if (d.has_terms[i]) irradiance += t.direct + t.cluster;
            for (int a = c; a >= 0; a = h[a].parent) irradiance += G[static_cast<std::size_t>(a)] + d.V[static_cast<std::size_t>(a)];
            next[k] = rho_[i].cwiseProduct(irradiance) / std::numbers::pi;
            change = std::max(change, (next[k] - D[i]).cwiseAbs().maxCoeff());
        }
        for (std::size_t k = 0; k < leaves.size(); ++k) D[static_cast<std::size_t>(leaves[k])] = next[k];
        pull();
        if (change <= tolerance * d.scale) break;
    }
    return D;
}

// After a dense solve: the propagation's bookkeeping made exact (every gather from the whole
// difference, nothing unshot).
void VirtualInfluence::Impl::resync() {
    std::fill(G.begin(), G.end(), Eigen::Vector3d::Zero());
    for (const Link& l : links) {
        G[static_cast<std::size_t>(l.receiver)] +=
            (kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real)) * self.d_[static_cast<std::size_t>(l.source)];
    }
    const Hierarchy& h = self.radiosity_.hierarchy();
    for (std::size_t c = 0; c < terms.size(); ++c) {
        if (!has_terms[c] || h[static_cast<int>(c)].retired) continue;
        LeafTerms& t = terms[c];
        t.cl.setZero();
        for (const Correction& k : t.corrections) {
            const auto s = static_cast<std::size_t>(k.source);
            t.cl += k.coef * (base.radiance[s] + self.d_[s]);
        }
    }
    std::fill(U.begin(), U.end(), Eigen::Vector3d::Zero());
    for (int e : worklist) queued[static_cast<std::size_t>(e)] = 0;
    worklist.clear();
}

// The outputs: B = B~ + D, the virtual faces' radiance, what changed, the counts.
void VirtualInfluence::Impl::finish() {
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    grow();
    const std::size_t n = h.elements().size();
    for (std::size_t i = 0; i < n; ++i) self.radiance_[i] = self.tilde_[i] + self.d_[i];
    for (const ObjectState& s : objects) {
        for (std::size_t k = 0; k < s.faces.size(); ++k) {
            std::vector<int> leaves;
            h.leavesUnder(h.root(s.faces[k]), leaves);
            for (int l : leaves) {
                self.radiance_[static_cast<std::size_t>(l)] = s.present && k < s.face_radiance.size() ? s.face_radiance[k] : Eigen::Vector3d::Zero();
                self.d_[static_cast<std::size_t>(l)].setZero();
            }
        }
    }
    self.changed_faces_.clear();
    for (std::size_t f = 0; f < face_dirty.size() && f < rad.realFaceCount(); ++f) {
        if (face_dirty[f]) self.changed_faces_.push_back(static_cast<int>(f));
    }
    InfluenceStats& st = self.stats_;
    st.leaves = 0;
    st.refined = 0;
    st.corrections = 0;
    for (int e : rad.leaves(Mode::kReal)) {
        ++st.leaves;
        if (sub[static_cast<std::size_t>(e)]) ++st.refined;
    }
    for (std::size_t i = 0; i + 1 < corr_offsets.size(); ++i) st.corrections += corr_offsets[i + 1] - corr_offsets[i];
    st.cluster_links = 0;
    for (const ObjectState& s : objects) st.cluster_links += static_cast<int>(s.cluster_links.size());
    st.shafts = index ? static_cast<int>(index->size()) : 0;
    st.stored = h.storedCount();
}

}  // namespace commonlight::lighting
