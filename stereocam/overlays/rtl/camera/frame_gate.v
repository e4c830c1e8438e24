// Language: Verilog 2005

`include "prelude.vh"

/*
 * frame_gate: an AXI4-Stream stage that never holds its input and forwards whole frames, or none
 * (stereocam/overlays/spec/frame_gate.py, "Behaviour, clock by clock"; stereocam/overlays/rtl/camera/README.md).
 *
 * s_axis_tready is tied high: every beat offered is taken. A frame (from a beat with TUSER to the
 * next one) is admitted only if the gate holds no committed beat when its TUSER beat arrives;
 * otherwise it is dropped whole. Beats of an admitted frame are written into a block RAM FIFO of
 * DEPTH beats; a line becomes visible to the read side (committed) when its TLAST beat is written,
 * so only whole lines leave. A beat of an admitted frame that finds DEPTH beats held cuts the
 * frame: the write pointer goes back to the last commit (the partial line is forgotten) and the
 * rest of the frame is dropped; the committed lines still go out. A TUSER while a partial line is
 * held (malformed input) forgets that line the same way.
 *
 * Read side: the RAM (rc_ram, two clocks) feeds a 4-word output FIFO (rc_fifo) that drives
 * m_axis; a read is issued only when that FIFO has room for it and every read in flight (credits).
 *
 * Latency: a line's first beat is offered on m_axis 4 clocks after the clock its TLAST is taken in
 * (gate empty before). Throughput: one beat per clock in and out. Frame and line boundaries: as
 * above; the gate never creates, reorders or alters a beat.
 *
 * Reset: aresetn (aclk, active low, synchronous) empties the gate; the frame in progress is
 * dropped (beats before the first TUSER after reset are). frames_admitted_reg, frames_dropped_reg
 * and frames_cut_reg count frames (no port: visible in simulation).
 */
module frame_gate #
(
    parameter DEPTH = 1024
)
(
    input  wire        aclk,
    input  wire        aresetn,

    input  wire [63:0] s_axis_tdata,
    input  wire        s_axis_tvalid,
    output wire        s_axis_tready,
    input  wire        s_axis_tuser,
    input  wire        s_axis_tlast,

    output wire [63:0] m_axis_tdata,
    output wire        m_axis_tvalid,
    input  wire        m_axis_tready,
    output wire        m_axis_tuser,
    output wire        m_axis_tlast
);

localparam AW = $clog2(DEPTH);                      // RAM of 2**AW words (spec.ram_words)
localparam PW = AW + 1;                             // pointers: occupancy up to DEPTH <= 2**AW
localparam integer DEPTH_I = DEPTH;
localparam [PW-1:0] CAPACITY = DEPTH_I[PW-1:0];
localparam ODEPTH = 4;                              // spec.OUTPUT_FIFO_DEPTH
localparam OCW = $clog2(ODEPTH + 1);
localparam WW = 66;                                 // RAM word {tuser, tlast, tdata}

reg rst_reg = 1'b1;

always @(posedge aclk) begin
    rst_reg <= !aresetn;
end

/*
 * Write side: admit, store, commit, cut
 */
reg [PW-1:0] wr_ptr_reg = {PW{1'b0}};               // next word to write (uncommitted words below it)
reg [PW-1:0] cm_ptr_reg = {PW{1'b0}};               // committed up to here
reg [PW-1:0] rd_ptr_reg = {PW{1'b0}};               // next word to read from the RAM
reg [PW-1:0] out_ptr_reg = {PW{1'b0}};              // words taken by m_axis
reg          pass_reg = 1'b0;                       // the current frame is admitted and not cut
reg [15:0]   frames_admitted_reg = 16'd0;
reg [15:0]   frames_dropped_reg = 16'd0;
reg [15:0]   frames_cut_reg = 16'd0;

wire [PW-1:0] held = wr_ptr_reg - out_ptr_reg;      // occupancy: every word written, not yet taken
wire          empty = cm_ptr_reg == out_ptr_reg;    // no committed word left anywhere
wire          partial = wr_ptr_reg != cm_ptr_reg;

wire          sof = s_axis_tvalid && s_axis_tuser;
wire          more = s_axis_tvalid && !s_axis_tuser && pass_reg;
wire          overflow = more && held >= CAPACITY;
wire          store = (sof && empty) || (more && !overflow);
wire [PW-1:0] waddr = sof ? cm_ptr_reg : wr_ptr_reg;     // a start of frame forgets a partial line
wire [PW-1:0] wnext = waddr + 1'b1;

always @(posedge aclk) begin
    if (rst_reg) begin
        wr_ptr_reg <= {PW{1'b0}};
        cm_ptr_reg <= {PW{1'b0}};
        pass_reg <= 1'b0;
    end else begin
        if (sof) begin
            pass_reg <= empty;
            if (partial) begin
                frames_cut_reg <= frames_cut_reg + 1'b1;
            end
            if (empty) begin
                frames_admitted_reg <= frames_admitted_reg + 1'b1;
            end else begin
                frames_dropped_reg <= frames_dropped_reg + 1'b1;
            end
        end else if (overflow) begin
            pass_reg <= 1'b0;
            frames_cut_reg <= frames_cut_reg + 1'b1;
        end
        if (store) begin
            wr_ptr_reg <= wnext;
            if (s_axis_tlast) begin
                cm_ptr_reg <= wnext;
            end
        end else if (sof || overflow) begin
            wr_ptr_reg <= cm_ptr_reg;
        end
    end
end

/*
 * Read side: RAM reads with credits into the output FIFO
 */
wire [OCW-1:0] ocount;
reg  [1:0]     inflight_reg = 2'd0;                 // reads issued whose word is not in the FIFO yet
reg            rv1_reg = 1'b0, rv2_reg = 1'b0;      // a read's word: RAM output register, then rdata
wire [WW-1:0]  rdata;
wire [WW-1:0]  out_word;

wire [OCW:0] credit_need = {1'b0, ocount} + {{(OCW - 1){1'b0}}, inflight_reg} + 1'b1;
wire         issue = !rst_reg && cm_ptr_reg != rd_ptr_reg && credit_need <= ODEPTH;
wire         pop = m_axis_tvalid && m_axis_tready;

always @(posedge aclk) begin
    if (rst_reg) begin
        rd_ptr_reg <= {PW{1'b0}};
        out_ptr_reg <= {PW{1'b0}};
        inflight_reg <= 2'd0;
        rv1_reg <= 1'b0;
        rv2_reg <= 1'b0;
    end else begin
        if (issue) begin
            rd_ptr_reg <= rd_ptr_reg + 1'b1;
        end
        if (pop) begin
            out_ptr_reg <= out_ptr_reg + 1'b1;
        end
        inflight_reg <= inflight_reg + {1'b0, issue} - {1'b0, rv2_reg};
        rv1_reg <= issue;
        rv2_reg <= rv1_reg;
    end
end

rc_ram #(.WIDTH(WW), .DEPTH(1 << AW), .AW(AW)) ram_inst (
    .clk(aclk),
    .we(store), .waddr(waddr[AW-1:0]), .wdata({s_axis_tuser, s_axis_tlast, s_axis_tdata}),
    .re(issue), .raddr(rd_ptr_reg[AW-1:0]), .rdata(rdata)
);

// the reads are issued against credits: the FIFO is never full when a word arrives, so
// s_ready is left open
// verilator lint_off PINCONNECTEMPTY
rc_fifo #(.WIDTH(WW), .DEPTH(ODEPTH), .SHOW_AHEAD(1)) ofifo_inst (
    .clk(aclk), .rst(rst_reg),
    .s_data(rdata), .s_valid(rv2_reg), .s_ready(),
    .m_data(out_word), .m_valid(m_axis_tvalid), .m_ready(m_axis_tready), .count(ocount)
);
// verilator lint_on PINCONNECTEMPTY

assign s_axis_tready = 1'b1;
assign m_axis_tdata = out_word[63:0];
assign m_axis_tlast = out_word[64];
assign m_axis_tuser = out_word[65];

endmodule

`resetall
