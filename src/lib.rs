//! PCL bridge (being written).
