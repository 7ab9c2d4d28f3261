//! Writes a simulated run as EuRoC/ASL datasets, one per robot, plus the world's ground truth
//! (owned by the dataset helper).
