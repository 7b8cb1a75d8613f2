use std::path::Path;

use anyhow::Result;
use mmnormd::radar::{RadarProfile, RxLayout};

pub fn run(cfg: &Path) -> Result<()> {
    let p = RadarProfile::from_cfg_file(cfg)?;
    println!("profile {}", cfg.display());
    println!(
        "  ramp start        {:.6} GHz (code {})",
        p.ramp_start_frequency_hz() / 1e9,
        p.start_frequency_code
    );
    println!(
        "  slope             {:.6} MHz/µs (code {})",
        p.slope_hz_per_s() / 1e12,
        p.slope_code
    );
    println!(
        "  ADC start         {:.2} µs, ramp end {:.2} µs, idle {:.2} µs",
        p.adc_start_time_s() * 1e6,
        p.ramp_end_time_s() * 1e6,
        p.idle_time_s() * 1e6
    );
    println!(
        "  samples           {} at {:.0} ksps ({}-bit complex)",
        p.samples_per_chirp,
        p.sample_rate_hz / 1e3,
        p.adc_bits
    );
    println!(
        "  sample 0          {:.6} GHz (λ0 = {:.4} mm)",
        p.first_sample_frequency_hz() / 1e9,
        p.first_sample_wavelength_m() * 1e3
    );
    println!("  step per sample   {:.3} Hz", p.frequency_step_hz());
    println!(
        "  sampled bandwidth {:.4} GHz",
        p.sampled_bandwidth_hz() / 1e9
    );
    println!(
        "  range resolution  {:.4} m, max range {:.2} m",
        p.range_resolution_m(),
        p.max_range_m()
    );
    println!(
        "  frames            {} every {:.3} ms ({} chirp(s) × {} loop(s))",
        p.frames,
        p.frame_period_s() * 1e3,
        p.chirps_per_loop,
        p.chirp_loops
    );
    let offsets: Vec<String> = p
        .rx_offsets_m(RxLayout::Iwr1443Boost)
        .iter()
        .map(|o| format!("{:.3} mm", o * 1e3))
        .collect();
    println!(
        "  RX channels       {:?}, IWR1443BOOST offsets {}",
        p.rx_channels,
        offsets.join(", ")
    );
    Ok(())
}
