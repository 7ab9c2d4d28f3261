pub mod sim_run;
