// Translation unit that anchors the static library until its sources land.
namespace brdfkit { int fit_anchor = 0; }
