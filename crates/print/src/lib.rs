//! What cellinject's commands print and write, as values, after ripgrep's
//! `grep-printer`: the text summaries a person reads, the tables ([`table::Table`],
//! aligned text or Markdown), the CSV files and the charts ([`cellinject_plot::Chart`])
//! made from the libraries' typed reports. Pure: strings and charts out, no IO; the
//! binary (and any other front end) writes them where they belong.

pub mod calibrate;
pub mod design;
pub mod dic;
pub mod experiment;
pub mod fea;
pub mod hinge;
pub mod hysteresis;
pub mod model;
pub mod plate;
pub mod run;
pub mod table;
pub mod vision;
