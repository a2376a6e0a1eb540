// Translation unit that anchors the static library until its sources land.
namespace brdfkit { int data_synth_anchor = 0; }
