// TEMPORARY: removed when the first sim source lands.
namespace partloc::sim {}
