// harness.cpp: a stream core (rectify_core or stereo_core, compiled by Verilator) as a program
// that Python drives with whole frames and register accesses over a pipe
// (stereocam/overlays/rtl/core.py builds it and runs the rectify core, stereo_core.py the stereo
// core). The build writes harness_top.h beside it: the Verilated top's headers, `using
// HarnessTop = V<top>;` and whether every output of the top comes from a register
// (HARNESS_REGISTERED_OUTPUTS, below). Both tops have the same ports (AXI4-Lite s_axil_*,
// AXI4-Stream s_axis_* in of 64 bits, m_axis_* out of 64 or 32 bits, carried in a u64 either
// way) and STATUS.BUSY at the same place. No per-beat traffic crosses the pipe: the
// AXI4-Stream and AXI4-Lite handshakes are all done here, at full simulation speed.
//
// Protocol. Binary, little-endian, one request on stdin then one reply on stdout, in
// order. A request is a 1-byte opcode and its fixed fields; a reply starts with a status
// byte: 'K' (done; the op's fields follow) or 'E' (failed; u32 length, then that many
// bytes of message; the core's state is then whatever the failure left). The
// simulation's own prints ($display) go to stderr, never into the replies.
//
//   'R' reset                      -> K u64 clock
//       aresetn low for 16 clocks, then clocks until the register block takes writes
//       (rc_regs holds its AXI ready low for 128 clocks after reset). Clock = clocks since
//       the program started.
//   'W' u32 offset, u32 value      -> K u32 bresp
//       AXI4-Lite write (WSTRB 0xf; AW and W offered together).
//   'r' u32 offset                 -> K u32 value, u32 rresp
//       AXI4-Lite read.
//   'S' u64 seed, u32 gap, u32 backpressure, u32 quiet, u32 stall   -> K
//       Stream settings: before each input beat TVALID stays low for a clock with
//       probability gap/1000 (repeatedly), and each clock the output's TREADY is low with
//       probability backpressure/1000, from a generator seeded with seed (0, 0: full
//       speed). quiet and stall: the end of a frame, below. Defaults 0, 0, 0, 64, 20000.
//   'F' u32 height, u32 width, u64 max_clocks, height*width x u64 beat   -> K result
//       Streams one input frame (TUSER on its first beat, TLAST on the last beat of each
//       line; any size, wrong ones included) while collecting output beats, then keeps
//       clocking until the output has been quiet (no TVALID) for `quiet` clocks and
//       STATUS.BUSY reads 0 (end "idle"), or has been quiet for `stall` clocks with BUSY 1
//       (end "waiting": the core needs more input, e.g. after a frame with too few lines,
//       which it can only end at the next TUSER). If no beat moves on either stream for
//       `stall` clocks while input remains, TVALID is withdrawn and the rest of the frame
//       is not sent (end "stalled", e.g. CONTROL.ENABLE 0); after max_clocks (0: no limit)
//       likewise (end "limit").
//   'C' u64 n                      -> K result
//       n clocks with no input, collecting output beats.
//   'Q' quit                       -> K, then the program exits.
//
//   result = u64 clocks (all the clocks the op took), u64 clocks_to_last (clocks from
//            the op's start to its last stream beat, in or out), u64 beats_in (input beats
//            accepted), u64 in_waits and out_waits (clocks with TVALID high and TREADY
//            low on the input and on the output: backpressure seen), u32 end (0 idle,
//            1 waiting, 2 stalled, 3 limit; 'C': 0),
//            u32 n, then n x u64 TDATA, then n x u8 (bit 0 TUSER, bit 1 TLAST) of the
//            output beats since the previous result, in order (a beat that leaves during
//            a register access comes with the next result).
//
// One clock: the inputs chosen for it are applied, every handshake (valid && ready) is
// sampled, then aclk rises (one evaluation of the model); the inputs for the next clock are
// chosen from what moved. (AXI4-Lite handshakes are sampled only during a register access:
// no VALID of the harness is high otherwise.) Sampling needs no evaluation with aclk low
// when every output of the top comes straight from a register (or is a constant), as in rectify_core:
// the outputs after a rising edge stay what they are until the next one, whatever the
// harness drives meanwhile, and the edge's evaluation settles the new inputs before it
// clocks the registers. The model sees the edge in that single evaluation because the
// harness clears the clock value Verilator remembered from the previous one (see
// forget_clock); with a Verilator that has no such member, or a top with an output that
// depends on an input through logic only (stereo_core's s_axis_tready on s_axis_tuser;
// HARNESS_REGISTERED_OUTPUTS false), the harness evaluates the low phase as well, which settles
// those outputs before they are sampled (same results, about 5 % slower).
//
// Speed: a 752x480 frame is about 750,000 clocks; the model's evaluation is 98 % of a
// clock's instructions and this loop about 1 %, so the harness no longer matters: the RTL's
// size sets the rate.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>
#include <unistd.h>

#include "harness_top.h"  // written by the build: HarnessTop, HARNESS_REGISTERED_OUTPUTS
#include "rectify_regs.h"  // generated from RECTIFY_MAP (python -m stereocam.overlays.spec.verilog)
#include "verilated.h"

namespace {

constexpr uint64_t AXIL_TIMEOUT = 100000;  // clocks a register access may wait
enum End : uint32_t { END_IDLE = 0, END_WAITING = 1, END_STALLED = 2, END_LIMIT = 3 };

FILE* g_in = nullptr;   // requests
FILE* g_out = nullptr;  // replies (the process's original stdout)

struct Failure : std::runtime_error {
    using std::runtime_error::runtime_error;
};

void read_exact(void* dst, size_t n) {
    if (n && fread(dst, 1, n, g_in) != n) throw Failure("end of input");
}
template <typename T> T get() {
    T v;
    read_exact(&v, sizeof v);
    return v;
}
void put_bytes(const void* src, size_t n) {
    if (n && fwrite(src, 1, n, g_out) != n) throw Failure("cannot write the reply");
}
template <typename T> void put(T v) { put_bytes(&v, sizeof v); }

// Verilator 5 detects the rising edge of aclk by comparing it with the value it saw at the
// previous evaluation, kept in the model's root. Setting that to 0 makes the next evaluation
// with aclk 1 a rising edge without an evaluation with aclk 0 before it. Returns false (and
// does nothing) when the root has no such member, e.g. another Verilator version.
template <typename Root>
auto forget_clock(Root* root, int) -> decltype(root->__Vtrigprevexpr___TOP__aclk__0 = 0, bool()) {
    root->__Vtrigprevexpr___TOP__aclk__0 = 0;
    return true;
}
template <typename Root> bool forget_clock(Root*, long) { return false; }

// What moved on the last clock edge (sampled just before it).
struct Moved {
    bool in = false, out = false, out_valid = false, aw = false, w = false, b = false, ar = false, r = false;
    uint32_t bresp = 0, rdata = 0, rresp = 0;
};

class Harness {
  public:
    Harness() : ctx_(new VerilatedContext), top_(new HarnessTop(ctx_.get())) {
        top_->aclk = 0;
        top_->aresetn = 0;
        top_->s_axil_wstrb = 0xf;
        top_->m_axis_tready = 1;  // lowered only with backpressure (tick)
        top_->eval();
        top_->aclk = 1;  // stays 1 when each clock is a single evaluation (tick)
        one_eval_ = HARNESS_REGISTERED_OUTPUTS && forget_clock(top_->rootp, 0);
        if (!one_eval_) top_->aclk = 0;
    }
    ~Harness() { top_->final(); }

    uint64_t clock() const { return clock_; }

    void settings(uint64_t seed, uint32_t gap, uint32_t backpressure, uint32_t quiet, uint32_t stall) {
        rng_.seed(seed);
        gap_ = gap;
        backpressure_ = backpressure;
        top_->m_axis_tready = 1;
        quiet_ = quiet ? quiet : 1;
        stall_ = stall ? stall : 1;
    }

    void reset() {
        drop_input();
        top_->aresetn = 0;
        for (int i = 0; i < 16; ++i) tick();
        top_->aresetn = 1;
        for (uint64_t i = 0; !top_->s_axil_awready; ++i) {
            if (i > AXIL_TIMEOUT) throw Failure("AWREADY never rose after reset");
            tick();
        }
    }

    uint32_t write(uint32_t offset, uint32_t value) {
        AxilAccess access(axil_);
        top_->s_axil_awaddr = offset;
        top_->s_axil_awvalid = 1;
        top_->s_axil_wdata = value;
        top_->s_axil_wvalid = 1;
        top_->s_axil_bready = 1;
        for (uint64_t i = 0;; ++i) {
            if (i > AXIL_TIMEOUT) throw Failure("AXI4-Lite write at " + hex(offset) + " got no response");
            tick();
            if (moved_.aw) top_->s_axil_awvalid = 0;
            if (moved_.w) top_->s_axil_wvalid = 0;
            if (moved_.b) break;
        }
        top_->s_axil_bready = 0;
        return moved_.bresp;
    }

    uint32_t read(uint32_t offset, uint32_t* resp) {
        AxilAccess access(axil_);
        top_->s_axil_araddr = offset;
        top_->s_axil_arvalid = 1;
        top_->s_axil_rready = 1;
        for (uint64_t i = 0;; ++i) {
            if (i > AXIL_TIMEOUT) throw Failure("AXI4-Lite read at " + hex(offset) + " got no response");
            tick();
            if (moved_.ar) top_->s_axil_arvalid = 0;
            if (moved_.r) break;
        }
        top_->s_axil_rready = 0;
        if (resp) *resp = moved_.rresp;
        return moved_.rdata;
    }

    // The 'F' op: returns the end reason; the output beats are in out_data_/out_flags_.
    uint32_t frame(const std::vector<uint64_t>& beats, uint32_t width, uint64_t max_clocks) {
        begin_op();
        in_ = &beats;
        in_width_ = width;
        next_in_ = 0;
        in_col_ = 0;
        out_data_.reserve(out_data_.size() + beats.size());
        out_flags_.reserve(out_flags_.size() + beats.size());
        offer_next();
        uint64_t still = 0;  // clocks with nothing moving on either stream
        while (next_in_ < beats.size()) {
            tick();
            still = (moved_.in || moved_.out) ? 0 : still + 1;
            if (still >= stall_ || (max_clocks && clock_ - start_ >= max_clocks)) {
                drop_input();
                return still >= stall_ ? END_STALLED : END_LIMIT;
            }
        }
        in_ = nullptr;
        // Drain: wait for a quiet output, then ask the core whether it is busy.
        uint64_t quiet = 0, next_check = quiet_;
        while (true) {
            if (max_clocks && clock_ - start_ >= max_clocks) return END_LIMIT;
            tick();
            if (moved_.out_valid) {
                quiet = 0;
                next_check = quiet_;
                continue;
            }
            if (++quiet >= stall_) return END_WAITING;
            if (quiet >= next_check) {
                size_t before = out_data_.size();
                uint64_t c0 = clock_;
                bool busy = (read(RC_REG_STATUS, nullptr) >> RC_STATUS_BUSY) & 1;
                if (out_data_.size() != before) {
                    quiet = 0;
                    next_check = quiet_;
                    continue;
                }
                if (!busy) return END_IDLE;
                quiet += clock_ - c0;
                next_check = quiet + quiet_;
            }
        }
    }

    void idle_clocks(uint64_t n) {
        begin_op();
        for (uint64_t i = 0; i < n; ++i) tick();
    }

    void put_result(uint32_t end) {
        put<uint64_t>(clock_ - start_);
        put<uint64_t>(last_move_ ? last_move_ - start_ : 0);
        put<uint64_t>(beats_in_);
        put<uint64_t>(in_waits_);
        put<uint64_t>(out_waits_);
        put<uint32_t>(end);
        put<uint32_t>(static_cast<uint32_t>(out_data_.size()));
        put_bytes(out_data_.data(), out_data_.size() * sizeof(uint64_t));
        put_bytes(out_flags_.data(), out_flags_.size());
        out_data_.clear();
        out_flags_.clear();
    }

  private:
    static std::string hex(uint32_t v) {
        char buf[16];
        snprintf(buf, sizeof buf, "0x%03x", v);
        return buf;
    }

    bool chance(uint32_t permille) { return permille && rng_() % 1000 < permille; }

    // Marks a register access in flight (tick samples the AXI4-Lite handshakes only then).
    struct AxilAccess {
        explicit AxilAccess(bool& flag) : flag_(flag) { flag_ = true; }
        ~AxilAccess() { flag_ = false; }
        AxilAccess(const AxilAccess&) = delete;
        AxilAccess& operator=(const AxilAccess&) = delete;
        bool& flag_;
    };

    void begin_op() {
        start_ = clock_;
        last_move_ = 0;
        beats_in_ = 0;
        in_waits_ = 0;
        out_waits_ = 0;
    }

    // Put the next input beat on s_axis (or leave TVALID low for a gap).
    void offer_next() {
        top_->s_axis_tvalid = 0;
        if (!in_ || next_in_ >= in_->size() || chance(gap_)) return;
        top_->s_axis_tdata = (*in_)[next_in_];
        top_->s_axis_tuser = next_in_ == 0;
        top_->s_axis_tlast = in_width_ && in_col_ == in_width_ - 1;
        top_->s_axis_tvalid = 1;
    }

    void drop_input() {
        in_ = nullptr;
        top_->s_axis_tvalid = 0;
    }

    // One clock. The common path (a frame without gaps or backpressure) draws no random
    // numbers, keeps TREADY high without writing it, and samples only the two streams: the
    // AXI4-Lite handshakes are sampled while a register access is in flight.
    void tick() {
        if (backpressure_) top_->m_axis_tready = !chance(backpressure_);
        if (!one_eval_) {
            top_->aclk = 0;
            top_->eval();
        }
        const bool in_valid = top_->s_axis_tvalid, in_ready = top_->s_axis_tready;
        const bool out_valid = top_->m_axis_tvalid, out_ready = top_->m_axis_tready;
        moved_.in = in_valid && in_ready;
        moved_.out_valid = out_valid;
        moved_.out = out_valid && out_ready;
        in_waits_ += in_valid && !in_ready;
        out_waits_ += out_valid && !out_ready;
        if (axil_) {
            moved_.aw = top_->s_axil_awvalid && top_->s_axil_awready;
            moved_.w = top_->s_axil_wvalid && top_->s_axil_wready;
            moved_.b = top_->s_axil_bvalid && top_->s_axil_bready;
            moved_.bresp = top_->s_axil_bresp;
            moved_.ar = top_->s_axil_arvalid && top_->s_axil_arready;
            moved_.r = top_->s_axil_rvalid && top_->s_axil_rready;
            moved_.rdata = top_->s_axil_rdata;
            moved_.rresp = top_->s_axil_rresp;
        }
        if (moved_.out) {
            out_data_.push_back(top_->m_axis_tdata);
            out_flags_.push_back(static_cast<uint8_t>((top_->m_axis_tuser ? 1 : 0) | (top_->m_axis_tlast ? 2 : 0)));
        }
        top_->aclk = 1;
        if (one_eval_) forget_clock(top_->rootp, 0);
        top_->eval();
        ctx_->timeInc(1);
        ++clock_;
        if (moved_.in || moved_.out) last_move_ = clock_;
        if (moved_.in) {
            ++beats_in_;
            ++next_in_;
            if (++in_col_ == in_width_) in_col_ = 0;
            offer_next();
        } else if (in_ && !top_->s_axis_tvalid) {
            offer_next();  // end of a gap (a beat offered stays offered until taken)
        }
        if (VL_UNLIKELY(ctx_->gotFinish())) throw Failure("the simulation called $finish");
    }

    std::unique_ptr<VerilatedContext> ctx_;
    std::unique_ptr<HarnessTop> top_;
    std::mt19937_64 rng_{0};
    uint32_t gap_ = 0, backpressure_ = 0, quiet_ = 64, stall_ = 20000;
    uint64_t clock_ = 0, start_ = 0, last_move_ = 0, beats_in_ = 0, in_waits_ = 0, out_waits_ = 0;
    const std::vector<uint64_t>* in_ = nullptr;
    uint32_t in_width_ = 0;
    uint32_t in_col_ = 0;  // column of the beat next_in_ (next_in_ % in_width_)
    size_t next_in_ = 0;
    bool axil_ = false;    // a register access is in flight
    bool one_eval_ = false;  // a clock is one evaluation (forget_clock works)
    Moved moved_;
    std::vector<uint64_t> out_data_;
    std::vector<uint8_t> out_flags_;
};

void fail(const std::string& message) {
    put<uint8_t>('E');
    put<uint32_t>(static_cast<uint32_t>(message.size()));
    put_bytes(message.data(), message.size());
}

}  // namespace

int main(int argc, char** argv) {
    // Replies go to the original stdout; anything the simulation prints goes to stderr.
    int reply_fd = dup(1);
    dup2(2, 1);
    g_in = stdin;
    g_out = fdopen(reply_fd, "wb");
    if (!g_out) return 2;
    static char out_buf[1 << 16];
    setvbuf(g_out, out_buf, _IOFBF, sizeof out_buf);
    {
        uint32_t probe = 1;  // the protocol is little-endian, as the host's memory must be
        if (*reinterpret_cast<uint8_t*>(&probe) != 1) return 3;
    }
    Verilated::commandArgs(argc, argv);
    Harness h;
    std::vector<uint64_t> beats;
    while (true) {
        int op = fgetc(g_in);
        if (op == EOF) return 0;
        try {
            switch (op) {
            case 'R':
                h.reset();
                put<uint8_t>('K');
                put<uint64_t>(h.clock());
                break;
            case 'W': {
                uint32_t offset = get<uint32_t>(), value = get<uint32_t>();
                uint32_t bresp = h.write(offset, value);
                put<uint8_t>('K');
                put<uint32_t>(bresp);
                break;
            }
            case 'r': {
                uint32_t offset = get<uint32_t>(), rresp = 0;
                uint32_t value = h.read(offset, &rresp);
                put<uint8_t>('K');
                put<uint32_t>(value);
                put<uint32_t>(rresp);
                break;
            }
            case 'S': {
                uint64_t seed = get<uint64_t>();
                uint32_t gap = get<uint32_t>(), bp = get<uint32_t>(), quiet = get<uint32_t>(), stall = get<uint32_t>();
                h.settings(seed, gap, bp, quiet, stall);
                put<uint8_t>('K');
                break;
            }
            case 'F': {
                uint32_t height = get<uint32_t>(), width = get<uint32_t>();
                uint64_t max_clocks = get<uint64_t>();
                beats.resize(static_cast<size_t>(height) * width);
                read_exact(beats.data(), beats.size() * sizeof(uint64_t));
                uint32_t end = h.frame(beats, width, max_clocks);
                put<uint8_t>('K');
                h.put_result(end);
                break;
            }
            case 'C': {
                h.idle_clocks(get<uint64_t>());
                put<uint8_t>('K');
                h.put_result(END_IDLE);
                break;
            }
            case 'Q':
                put<uint8_t>('K');
                fflush(g_out);
                return 0;
            default:
                fail("unknown request " + std::to_string(op));
                fflush(g_out);
                return 1;  // the stream is out of step: nothing after this can be trusted
            }
        } catch (const Failure& e) {
            if (std::string(e.what()) == "end of input") return 0;
            fail(e.what());
        }
        fflush(g_out);
    }
}
